"""The two implementations of steps 2 to 4 (`gslam.mapupdate`): they agree on a scan inside the window
for the default settings, and no setting the compiled kernel ignores is routed to it."""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Literal

import numpy as np
import pytest

from gslam.config import FilterConfig
from gslam.filter import GSlamFilter
from gslam.mapupdate import select, wholemap, windowed
from gslam.mapupdate.noise import share_bounds
from gslam.pointmap import PointMap, cell_keys, distinct_maps
from gslam.scan import Scan, ScanGeometry
from pipelines.demo.world import World, ray_cast

GEOMETRY = ScanGeometry(361, -math.pi / 2, math.pi / 360, 30.0)
ROOM = World(
    np.array([[2.0, 1.5, 0.3]]),  # a pillar
    np.array([[-4.0, -3.0, 5.0, -3.0], [5.0, -3.0, 5.0, 4.0], [5.0, 4.0, -4.0, 4.0], [-4.0, 4.0, -4.0, -3.0]]),
)


def _scan(pose) -> Scan:
    ranges = ray_cast(ROOM, np.asarray(pose[:2]), pose[2] + GEOMETRY.bearings_rad, GEOMETRY.max_range_m)
    return Scan(0.0, ranges, GEOMETRY)


class _Draws:
    """A Generator stand-in that hands both implementations the same standard normal draws: the compiled
    kernel takes them as one (N, R, M, 2) array, the numpy steps as the range draws, then the bearing's."""

    def __init__(self, noise: np.ndarray) -> None:
        self.noise = noise
        self.flat = [noise[..., 0].ravel().astype(float), noise[..., 1].ravel().astype(float)]

    def standard_normal(self, size, dtype=None):
        out = self.flat.pop(0)
        assert out.shape == (size,)
        return out

    def spawn(self, k):
        """The compiled update's shares (`gslam.mapupdate.noise`): each hands its particles' rows."""
        return [_Share(self.noise[a:b]) for a, b in share_bounds(len(self.noise), k)]


class _Share:
    def __init__(self, rows: np.ndarray) -> None:
        self.rows = rows

    def fill(self, out: np.ndarray) -> None:
        assert out.dtype == np.float32 and out.shape == self.rows.shape
        out[...] = self.rows


def _windowed(cfg: FilterConfig) -> windowed.WindowedUpdate:
    """The compiled update, its new points' noise taken from the `_Draws` stand-in."""
    update = windowed.WindowedUpdate(cfg, 1)
    update.noise.fill = lambda share, out: share.fill(out)
    return update


class _Recording:
    """A FilterConfig that records the settings read from it."""

    def __init__(self, cfg: FilterConfig) -> None:
        object.__setattr__(self, "_cfg", cfg)
        object.__setattr__(self, "read", set())

    def __getattr__(self, name):
        self.read.add(name)
        return getattr(self._cfg, name)


def _state(cfg: FilterConfig, seed: int = 0):
    """Two particles' maps after one scan of the room, and the next scan from nearby poses (every map point
    and return inside the window), with the draws for the update. The maps come from the numpy steps,
    which keep each map sorted by cell (their cell-mean prior relies on it; the kernel takes any order)."""
    rng = np.random.default_rng(seed)
    first = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    scan0 = _scan(first[0])
    empty = [PointMap.empty()] * 2
    noise0 = rng.standard_normal((2, int(scan0.returns.sum()), cfg.points_per_observation, 2), dtype=np.float32)
    maps, _, _, _ = wholemap.WholeMapUpdate(cfg)(empty, None, first, scan0, _Draws(noise0), np.zeros(2))
    poses = np.array([[0.30, 0.10, 0.05], [0.33, 0.08, 0.06]])
    scan = _scan(poses[0])
    noise = rng.standard_normal((2, int(scan.returns.sum()), cfg.points_per_observation, 2), dtype=np.float32)
    return maps, poses, scan, noise, np.array([-3.0, -5.0])


def test_the_two_implementations_agree_on_a_scan_inside_the_window():
    # New points drawn 2 cm about the returns: spread enough that most cells' most probable point stands out
    # by more than the numpy sort's 11 bits of p (at the default 5 mm most draws tie there)
    cfg = FilterConfig(particles=2, range_sigma_m=0.02)
    assert windowed.supports(cfg) and isinstance(select(cfg), windowed.WindowedUpdate)
    maps, poses, scan, noise, matched = _state(cfg)
    a_maps, a_layout, a_like, a_total = _windowed(cfg)(maps, distinct_maps(maps), poses, scan, _Draws(noise), matched)
    b_maps, b_layout, b_like, b_total = wholemap.WholeMapUpdate(cfg)(maps, None, poses, scan, _Draws(noise), matched)
    np.testing.assert_array_equal(a_like, b_like)  # the matcher's weight, the same in both
    assert a_layout is not None and b_layout is None
    assert a_total == b_total > 500  # the same number of points kept: one in each cell of the walls
    for a, b, before in zip(a_maps, b_maps, maps, strict=True):
        ka, kb = cell_keys(a.xy, cfg.cell_size_m), cell_keys(b.xy, cfg.cell_size_m)
        assert len(np.unique(ka)) == len(ka) and len(np.unique(kb)) == len(kb)  # one point per cell
        ia, ib = np.argsort(ka), np.argsort(kb)
        np.testing.assert_array_equal(ka[ia], kb[ib])  # the same cells occupied
        # Each keeps its cell's most probable point; the numpy sort ranks p on 11 bits, so of points within
        # 2^-11 of each other it may keep another one than the kernel does.
        np.testing.assert_allclose(a.p[ia], b.p[ib], atol=2.0**-11, rtol=0)
        # Where both keep the same point (the same place, to the float32 the kernel stores maps in: 1e-6 m
        # within 10 m of the origin), its p is the same to float32's precision.
        same = np.hypot(*(a.xy[ia] - b.xy[ib]).T) < 1e-5
        assert same.sum() > 50
        np.testing.assert_allclose(a.p[ia][same], b.p[ib][same], atol=1e-6, rtol=0)
        assert not np.array_equal(np.sort(a.p), np.sort(before.p))  # the update did change the map


def _perturbed(cfg: FilterConfig):
    """Configs that differ from cfg in one setting each: (name, config)."""
    hints = typing.get_type_hints(FilterConfig)
    for f in dataclasses.fields(FilterConfig):
        value, tp = getattr(cfg, f.name), hints[f.name]
        if typing.get_origin(tp) is Literal:
            others = [v for v in typing.get_args(tp) if v != value]
        elif isinstance(value, bool):
            others = [not value]
        elif isinstance(value, int):
            others = [value + 1]
        elif isinstance(value, float):
            others = [value * 0.75 if value else 0.01]
        elif value is None:
            others = [0.5]
        elif isinstance(value, tuple):
            others = [tuple(v * 1.5 for v in value)]
        else:
            others = []
        for other in others:
            try:
                yield f.name, dataclasses.replace(cfg, **{f.name: other})
            except ValueError:
                continue  # out of the setting's range


def test_no_setting_the_compiled_kernel_ignores_is_routed_to_it():
    """For the default settings and each setting changed on its own: where the filter routes the update to
    the compiled kernel, every setting the numpy steps read must be one the kernel reads (windowed.OPTIONS)
    or one it requires at its value (windowed.REQUIRED). An option added to the numpy steps only is then
    caught here, instead of being silently ignored on the default path."""
    base = FilterConfig(particles=2)
    maps, poses, scan, noise, matched = _state(base)
    routed, declared = 0, set(windowed.OPTIONS) | set(windowed.REQUIRED)
    for name, cfg in [("(defaults)", base), *_perturbed(base)]:
        if cfg.particles != 2 or cfg.points_per_observation != base.points_per_observation:
            continue  # the state's shape
        compiled = windowed.supports(cfg)
        flt = GSlamFilter(cfg, np.zeros(3), threads=1)
        assert isinstance(flt.map_update, windowed.WindowedUpdate) == compiled, name
        numpy_cfg = _Recording(cfg)
        wholemap.WholeMapUpdate(numpy_cfg)(maps, None, poses, scan, np.random.default_rng(0), matched)
        assert numpy_cfg.read <= set(wholemap.OPTIONS), (name, numpy_cfg.read - set(wholemap.OPTIONS))
        if not compiled:
            continue
        routed += 1
        ignored = numpy_cfg.read - declared
        assert not ignored, f"with {name} changed, the compiled update ignores {sorted(ignored)}"
        kernel_cfg = _Recording(cfg)
        update = _windowed(cfg)
        update.cfg = kernel_cfg
        update(maps, distinct_maps(maps), poses, scan, _Draws(noise), matched)
        assert kernel_cfg.read <= set(windowed.OPTIONS), (name, kernel_cfg.read - set(windowed.OPTIONS))
    assert routed > 30  # most settings leave the update on the compiled path


@pytest.mark.parametrize(
    "setting",
    [
        {"map_update": "observed"},
        {"observation_unit": "scan"},
        {"prior_interpolation": "idw"},
        {"free_space_beams": 2},
        {"prune_relative": True},
        {"weighting": "beam_sum"},
        {"max_points_per_cell": 0},
    ],
)
def test_a_reading_the_kernel_does_not_implement_runs_the_numpy_steps(setting):
    cfg = FilterConfig(**setting)
    assert not windowed.supports(cfg)
    assert isinstance(GSlamFilter(cfg, np.zeros(3), threads=1).map_update, wholemap.WholeMapUpdate)
    with pytest.raises(ValueError, match="does not implement"):
        windowed.WindowedUpdate(cfg, 1)
