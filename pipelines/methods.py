"""The SLAM methods a run can use: one registry, read by the command line, the runner, bench and sweep.

A method is a filter with the interface of `gslam.filter.SlamFilter` (its module in `gslam/` or
`gslam/baselines/`) and one `Method` line in `REGISTRY` that builds it from the run's options. A new
baseline is that module plus its line here (and its row of the paper's Table 4 in
`pipelines.bench.carpark`, if the paper has one). This module imports nothing heavy: the command line
reads the names before numpy is loaded; each builder imports its filter when it is called.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    import numpy as np

    from gslam.config import FilterConfig
    from gslam.filter import SlamFilter


class BuildOptions(Protocol):
    """What a builder reads of the run's options (`pipelines.run.runner.RunConfig` has them): named here
    rather than imported, so that this registry sits below the runner that uses it."""

    filter: FilterConfig
    method: str
    threads: int | None
    grid_cells: int | None


Builder = Callable[["BuildOptions", "np.ndarray", float], "SlamFilter"]
"""(the run's options, the initial pose, the range below which returns are ignored) -> the filter."""


@dataclass(frozen=True)
class Method:
    name: str
    """What the user types (`--method NAME`)."""
    summary: str
    """One line for the help."""
    build: Builder
    takes_points: bool = False
    """Whether M (new points per observation) applies: bench runs such a method for every (N, M)."""


def _gslam(cfg: BuildOptions, initial_pose: np.ndarray, min_range_m: float) -> SlamFilter:
    import numba

    from gslam.filter import GSlamFilter

    threads = cfg.threads or os.cpu_count() or 1
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    return GSlamFilter(cfg.filter, initial_pose, threads=threads)


def _fastslam(version: int) -> Builder:
    def build(cfg: BuildOptions, initial_pose: np.ndarray, min_range_m: float) -> SlamFilter:
        from gslam.baselines.fastslam import FastSlamConfig, FastSlamFilter

        fs = FastSlamConfig(
            particles=cfg.filter.particles,
            seed=cfg.filter.seed,
            version=version,
            resample_threshold=cfg.filter.resample_threshold,
        )
        return FastSlamFilter(fs, initial_pose, min_range_m)

    return build


def _grid(default_cells: int) -> Builder:
    def build(cfg: BuildOptions, initial_pose: np.ndarray, min_range_m: float) -> SlamFilter:
        from gslam.baselines.grid_rbpf import GridConfig, GridSlam

        grid = GridConfig(
            particles=cfg.filter.particles,
            seed=cfg.filter.seed,
            cells=cfg.grid_cells or default_cells,
            min_range_m=min_range_m,
            resample_threshold=cfg.filter.resample_threshold,
        )
        return GridSlam(grid, initial_pose)

    return build


def _odometry(cfg: BuildOptions, initial_pose: np.ndarray, min_range_m: float) -> SlamFilter:
    from gslam.baselines.dead_reckoning import DeadReckoning

    return DeadReckoning(initial_pose)


REGISTRY: tuple[Method, ...] = (
    Method("gslam", "G-SLAM: point maps (the filter of the paper)", _gslam, takes_points=True),
    Method("fastslam1", "FastSLAM 1.0 on pole landmarks", _fastslam(1)),
    Method("fastslam2", "FastSLAM 2.0 on pole landmarks", _fastslam(2)),
    Method("grid", "grid-map RBPF, about 3000 cells (the paper's)", _grid(3000)),
    Method("grid-hr", "grid-map RBPF, about 48000 cells (the paper's high resolution)", _grid(48000)),
    Method("odometry", "odometry alone: the noise-free motion model, no map (the yardstick)", _odometry),
)
METHODS: dict[str, Method] = {m.name: m for m in REGISTRY}
NAMES: tuple[str, ...] = tuple(METHODS)


def method(name: str) -> Method:
    """The method called `name`; ValueError naming the choices otherwise."""
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(f"method must be one of {', '.join(NAMES)}, got {name!r}") from None


def make_filter(cfg: BuildOptions, initial_pose: np.ndarray, self_return_range_m: float = 0.0) -> SlamFilter:
    """The filter of `cfg.method`, sharing the particle count, seed and range limit of cfg.filter (or,
    when that is None, the input's `self_return_range_m`)."""
    min_range_m = cfg.filter.min_range_m if cfg.filter.min_range_m is not None else self_return_range_m
    return method(cfg.method).build(cfg, initial_pose, min_range_m)
