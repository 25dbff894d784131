"""Grid occupancy RBPF SLAM (the paper's GOSLAM baselines): each particle holds a log-odds occupancy grid.

The grid covers a square of `size_m` centred on the initial pose, cut into about `cells` cells (the
paper: ~3000 for GOSLAM, ~48000 for GOSLAM HR, over the same area). Each scan marks the cells along
every beam free and the end cell occupied (rays sampled at half a cell); weights come from a likelihood
field (distance transform of the occupied cells). Grids are shared by reference after resampling and
copied when written (copy-on-write).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gslam.ancestry import AncestryTree
from gslam.filter import Predictor, StepResult
from gslam.resampling import continue_from_parents, reweight_and_resample
from gslam.scan import Scan, transform_points


@dataclass(frozen=True)
class GridConfig:
    particles: int = 8
    seed: int = 0
    cells: int = 3000
    """Approximate number of cells (the paper: 3000, or 48000 for the high-resolution variant)."""
    size_m: float = 80.0
    """Side of the square the grid covers, centred on the initial pose."""
    l_occupied: float = 0.85
    l_free: float = 0.4
    l_clamp: float = 6.0
    max_ray_m: float = 40.0
    """Free space is marked along returns and no-return beams up to this range."""
    weight_sigma_m: float = 0.3
    weight_floor: float = 0.05
    weight_tempering: float = 0.3
    weight_beam_stride: int = 2
    min_range_m: float = 1.0
    resample_threshold: float = 0.5

    @property
    def cell_m(self) -> float:
        return self.size_m / np.sqrt(self.cells)

    @property
    def side(self) -> int:
        return int(np.ceil(self.size_m / self.cell_m))


class GridSlam:
    """Rao-Blackwellised particle filter with a log-odds occupancy grid per particle."""

    def __init__(self, cfg: GridConfig, initial_pose: np.ndarray) -> None:
        self.cfg = cfg
        self.rng = np.random.default_rng(cfg.seed)
        self.poses = np.tile(np.asarray(initial_pose, float), (cfg.particles, 1))
        self.origin = np.asarray(initial_pose[:2], float) - cfg.size_m / 2
        empty = np.zeros((cfg.side, cfg.side), dtype=np.float32)
        empty.flags.writeable = False
        self.grids = [empty] * cfg.particles
        self.weights = np.full(cfg.particles, 1.0 / cfg.particles)
        self.tree = AncestryTree()

    def best_particle(self) -> int:
        return int(np.argmax(self.weights))

    def best_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        return self.tree.trajectory(self.best_particle())

    def cell_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ij = np.floor((xy - self.origin) / self.cfg.cell_m).astype(np.int64)
        i, j = ij[:, 0], ij[:, 1]
        side = self.cfg.side
        inside = (i >= 0) & (j >= 0) & (i < side) & (j < side)  # (column by column: `all(axis=1)` is slow)
        return i, j, inside

    def occupancy(self, particle: int) -> tuple[np.ndarray, np.ndarray, float]:
        """(occupancy probability grid (side, side) indexed [i along x, j along y], origin xy, cell size)."""
        g = self.grids[particle].astype(float)
        return 1.0 / (1.0 + np.exp(-g)), self.origin, self.cfg.cell_m

    def map_points(self, particle: int) -> tuple[np.ndarray, np.ndarray]:
        """Occupied cells (log-odds > 0) as cell centres with their occupancy probability."""
        g = self.grids[particle]
        i, j = np.nonzero(g > 0)
        xy = self.origin + (np.column_stack([i, j]) + 0.5) * self.cfg.cell_m
        return xy, 1.0 / (1.0 + np.exp(-g[i, j].astype(float)))

    def _distance_field(self, grid: np.ndarray) -> np.ndarray:
        """Distance [m] from each cell to the nearest occupied cell."""
        occupied = grid > 0
        if not occupied.any():
            return np.full(grid.shape, np.inf)
        from scipy.ndimage import distance_transform_edt  # only the grid baseline needs it

        return distance_transform_edt(~occupied) * self.cfg.cell_m

    def _log_likelihood(self, i: int, pts: np.ndarray, field: np.ndarray) -> float:
        ci, cj, inside = self.cell_of(transform_points(self.poses[i], pts))
        d = np.full(len(pts), np.inf)
        d[inside] = field[ci[inside], cj[inside]]
        score = np.where(np.isfinite(d), np.exp(-0.5 * (d / self.cfg.weight_sigma_m) ** 2), 0.0)
        return float(
            self.cfg.weight_tempering * np.log(self.cfg.weight_floor + (1 - self.cfg.weight_floor) * score).sum()
        )

    def _ray_points(self, scan: Scan) -> tuple[np.ndarray, np.ndarray]:
        """(free, end): the points every half cell along each beam up to its return or `max_ray_m`, and the
        returns within it, in the sensor frame (the same for every particle)."""
        cfg = self.cfg
        r = np.minimum(scan.occlusion_ranges_m, cfg.max_ray_m)
        hit = scan.returns & (scan.ranges_m <= cfg.max_ray_m)
        b = scan.geometry.bearings_rad
        step = cfg.cell_m / 2
        n = np.maximum((r / step).astype(np.int64), 0)
        beam = np.repeat(np.arange(len(r)), n)
        offs = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        dist = offs * step
        free_pts = np.column_stack([dist * np.cos(b[beam]), dist * np.sin(b[beam])])
        end_pts = np.column_stack([r[hit] * np.cos(b[hit]), r[hit] * np.sin(b[hit])])
        return free_pts, end_pts

    def _integrate(self, i: int, free_pts: np.ndarray, end_pts: np.ndarray) -> None:
        cfg = self.cfg
        g = self.grids[i].copy()  # copy-on-write
        fi, fj, fin = self.cell_of(transform_points(self.poses[i], free_pts))
        free = np.zeros_like(g, dtype=bool)
        free[fi[fin], fj[fin]] = True
        oi, oj, oin = self.cell_of(transform_points(self.poses[i], end_pts))
        occ = np.zeros_like(g, dtype=bool)
        occ[oi[oin], oj[oin]] = True
        g[free & ~occ] -= cfg.l_free
        g[occ] += cfg.l_occupied
        np.clip(g, -cfg.l_clamp, cfg.l_clamp, out=g)
        g.flags.writeable = False
        self.grids[i] = g

    def step(self, scan: Scan, predict: Predictor | None = None, intensities: np.ndarray | None = None) -> StepResult:
        cfg = self.cfg
        scan = Scan(scan.t_s, scan.ranges_m, scan.geometry, cfg.min_range_m)
        if predict is not None:
            self.poses = predict(self.poses, self.rng)
        idx = np.flatnonzero(scan.returns)[:: cfg.weight_beam_stride]
        pts = np.column_stack(
            [
                scan.ranges_m[idx] * np.cos(scan.geometry.bearings_rad[idx]),
                scan.ranges_m[idx] * np.sin(scan.geometry.bearings_rad[idx]),
            ]
        )
        log_like = np.zeros(cfg.particles)
        if len(self.tree):
            fields: dict[int, np.ndarray] = {}  # one field per distinct grid (shared after resampling)
            for i, g in enumerate(self.grids):
                if id(g) not in fields:
                    fields[id(g)] = self._distance_field(g)
                log_like[i] = self._log_likelihood(i, pts, fields[id(g)])
        free_pts, end_pts = self._ray_points(scan)
        for i in range(cfg.particles):  # per particle: vectorised over beams and ray samples
            self._integrate(i, free_pts, end_pts)
        self.weights, ess, parents = reweight_and_resample(self.weights, log_like, cfg.resample_threshold, self.rng)
        best = self.best_particle()
        result = StepResult(
            scan.t_s,
            self.poses.copy(),
            self.weights.copy(),
            ess,
            False,
            True,
            best,
            self.poses[best].copy(),
            int((self.grids[best] > 0).sum()),
            int(sum((g > 0).sum() for g in self.grids)),
            0,
        )
        self.tree.record(scan.t_s, self.poses)
        if parents is not None:
            self.poses, self.grids, self.weights = continue_from_parents(parents, self.poses, self.grids, self.tree)
            result.resampled = True
        return result
