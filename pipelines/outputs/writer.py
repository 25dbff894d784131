"""The interface of a result writer: `gslam process` holds a list of them and drives each the same way.

`start` once the run can begin (the input is open, the filter built), `step` after every scan,
`finish` at the end (also after an interruption: the result then holds the steps done), or `abort` when
the run cannot be completed: the writer then leaves nothing at its final path. Every writer writes to a
temporary file and renames it into place on `finish`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import numpy as np

    from gslam.filter import SlamFilter
    from pipelines.run.input_log import InputLog
    from pipelines.run.runner import Step


@dataclass
class RunStart:
    """What a writer learns when the run starts."""

    log: InputLog
    metadata: dict[str, dict[str, Any]]
    """The result's metadata: the software and command, the configuration, the input, the initialisation."""


@dataclass
class OccupancyMap:
    """The final trinary navigation grid (`pipelines.outputs.navigation_map`), when the run builds one."""

    t_s: float
    state: np.ndarray
    origin_xy_m: np.ndarray
    resolution_m: float


@dataclass
class RunEnd:
    """What a writer is given when the run ends."""

    filter: SlamFilter
    """The filter as the outputs see it (from the base where the laser is mounted off it)."""
    result: dict[str, Any]
    """The result's record (steps, times, memory, interrupted); a writer may add its own figures to it
    before the writers after it finish."""
    occupancy: OccupancyMap | None = None
    graph: dict[str, Any] | None = None
    """The back end's pose graph (`PoseGraphBackEnd.graph`, in the outputs' frame), when loop closure ran."""
    graph_scans: tuple[Any, Any] | None = None
    """Each graph node's returns in the map frame: (xy (K, 2), node index (K,)), what `--continue` reads."""
    sessions: list[dict[str, Any]] | None = None
    """The earlier mapping runs a continued run goes on from (`SLAM_SESSIONS_SCHEMA`'s items)."""
    earlier_maps: list[tuple[Any, Any]] | None = None
    """The maps of earlier runs apart from this run's map: (points (K, 2), probabilities (K,)) each, map
    1, 2, ... of `sessions`, each in its own frame (`map_1`, ...)."""
    earlier_graphs: list[tuple[dict[str, Any], tuple[Any, Any]] | None] | None = None
    """The pose graph under each of `earlier_maps` (None for one saved without): its record
    (`SLAM_GRAPH_SCHEMA`, with its `map`) and its nodes' returns as in `graph_scans`, in that map's frame."""


class ResultWriter(Protocol):
    path: Path

    def start(self, run: RunStart) -> None: ...

    def step(self, st: Step, flt: SlamFilter) -> None: ...

    def finish(self, end: RunEnd) -> Path: ...

    def abort(self) -> None: ...
