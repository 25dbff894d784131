"""Steps 2 to 4 of the algorithm for every particle, compiled and local to the scan.

For the default reading of the open points (per-point Bayes in log-odds, M new points around every
return, the cell-mean prior, pruning at an absolute threshold and at most `max_points_per_cell` points
per cell; `supports`) this does what `gslam.mapupdate.wholemap` does with numpy over whole maps, but each particle only
touches the points inside a window around the scan: the box of its pose and its returns' end points,
grown by a margin. Points outside the window are copied unchanged (neither observed as free nor hit),
so the work per update depends on the scan, not on the size of the map.

Per particle i (independent, so spread over threads with numba prange; the random draws are made
beforehand by generators spawned from the filter's seeded Generator, `gslam.mapupdate.noise`, so the
result does not depend on the thread count):

1. Every map point in the window is projected on its beam (eq. meas1) and gets q (eq. 6): a Gaussian
   bump around the return over `free_ratio` in front of it, 1 behind it or out of view; its p is
   updated in log-odds (eq. 7, binary semantic): logit p += log q.
2. M new points are drawn around every return, z_hat ~ N(z, R), mapped through the inverse of g; their
   prior is the mean p of the particle's points in the same cell (before this update; `prior_p0` where
   the cell is empty), updated with their own q.
3. Points with p < `prune_threshold` are dropped, and in each cell only the `max_points_per_cell` most
   probable stay (density control).
"""

from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np
from numba import njit, prange

from gslam.config import FilterConfig
from gslam.fastmath import fast_exp
from gslam.mapupdate.noise import NoiseDraws
from gslam.motion import wrap_angle_scalar
from gslam.pointmap import MAP_DTYPE, PointMap
from gslam.scan import Scan, window_boxes
from gslam.workqueue import next_index


def far_z2(hit_ratio: float, free_ratio: float) -> float:
    """The z^2 = (d / hit_sigma)^2 beyond which q (eq. 6) is exactly 1 or `free_ratio` in floating point:
    the bump's term (ratio difference x exp(-z^2 / 2)) is below an eighth of the spacing of the value it
    is added to, so the sum rounds to that value whatever exp returns there (within a factor 2)."""
    coef = max(abs(hit_ratio - 1.0), abs(hit_ratio - free_ratio))
    if coef == 0.0:
        return -1.0
    spacing = min(float(np.spacing(1.0)), float(np.spacing(np.float64(free_ratio)))) if free_ratio > 0 else 5e-324
    return 2.0 * (math.log(16.0 * coef) - math.log(spacing))


@njit(cache=True, inline="always")
def _q(d, hit_sigma, hit_ratio, free_ratio, far):
    """q (eq. 6) of a point `d` metres beyond the return of its beam (negative: in front of it); beyond
    `far` (`far_z2`) the Gaussian bump is not computed, as it cannot change q."""
    z2 = (d / hit_sigma) ** 2
    g = 0.0 if z2 > far else fast_exp(-0.5 * z2)  # beyond `far`, g x the ratio difference rounds away
    if d > 0.0:
        return 1.0 + (hit_ratio - 1.0) * g
    return free_ratio + (hit_ratio - free_ratio) * g


@njit(cache=True, inline="always")
def _logit_update(p, q):
    """logit p += log q (eq. 7, binary semantic), computed as p q / (p q + 1 - p)."""
    pq = p * q
    v = pq / (pq + 1.0 - p)
    return min(max(v, 1e-6), 1.0 - 1e-6)


@njit(cache=True)
def _update_one(
    lo,
    hi,
    map_xy,
    map_p,
    pose,
    ranges,
    ret_idx,
    start_rad,
    inc_rad,
    max_range,
    noise,
    sens,
    params,
    cell_count,
    cell_sum,
    cell_top,
    touched,
    cand_cell,
    cand_xy,
    cand_p,
    out_xy,
    out_p,
    out_lo,
):
    """Writes particle's new map into out_xy/out_p from out_lo; returns the number of points written.
    The window's points and the new ones are staged in the worker's cand_xy/cand_p, so the output needs
    room for the map and its new points only."""
    hit_sigma, hit_ratio, free_ratio, prune, cell_m, prior_p0, margin = (
        params[0],
        params[1],
        params[2],
        params[3],
        params[4],
        params[5],
        params[6],
    )
    keep_per_cell = int(params[7])
    far = params[8]
    no_return_free = params[9]  # how far a beam without a return observes free space (max_range: all the way)
    beams = ranges.shape[0]
    px, py, ph = pose[0], pose[1], pose[2]
    # The window: pose and end points of the returns, grown by the margin.
    x0, y0, x1, y1 = px, py, px, py
    for k in range(ret_idx.shape[0]):
        j = ret_idx[k]
        b = start_rad + inc_rad * j
        ex = px + ranges[j] * math.cos(ph + b)
        ey = py + ranges[j] * math.sin(ph + b)
        x0, y0, x1, y1 = min(x0, ex), min(y0, ey), max(x1, ex), max(y1, ey)
    x0 = math.floor((x0 - margin) / cell_m) * cell_m  # aligned with the global grid of cells
    y0 = math.floor((y0 - margin) / cell_m) * cell_m
    x1 += margin
    y1 += margin
    ny = int(math.floor((y1 - y0) / cell_m)) + 1
    # 1. Outside points are copied; window points are updated and go to a candidate list.
    n_out = out_lo
    n_cand = 0
    used = 0
    for k in range(lo, hi):
        x, y = map_xy[k, 0], map_xy[k, 1]
        if x < x0 or x >= x1 or y < y0 or y >= y1:
            out_xy[n_out, 0] = x
            out_xy[n_out, 1] = y
            out_p[n_out] = map_p[k]
            n_out += 1
            continue
        p = map_p[k]
        g = int(math.floor((x - x0) / cell_m)) * ny + int(math.floor((y - y0) / cell_m))
        if cell_count[g] == 0:
            touched[used] = g
            used += 1
            cell_sum[g] = 0.0
        cell_count[g] += 1
        cell_sum[g] += p  # the prior of new points: p before this update
        dx, dy = x - px, y - py
        r = math.sqrt(dx * dx + dy * dy)
        bearing = wrap_angle_scalar(math.atan2(dy, dx) - ph)
        j = int(math.floor((bearing - start_rad) / inc_rad + 0.5))
        if 0 <= j < beams and r < max_range and (ranges[j] < max_range or r < no_return_free):
            p = _logit_update(p, _q(r - ranges[j], hit_sigma, hit_ratio, free_ratio, far))
        cand_xy[n_cand, 0] = x
        cand_xy[n_cand, 1] = y
        cand_p[n_cand] = p
        cand_cell[n_cand] = g  # its cell, for step 3
        n_cand += 1
    # 2. New points around every return: z_hat ~ N(z, sigma_r), bearing ~ N(b, sigma_b); the small bearing
    # noise turns the return's direction by a rotation expanded to third order (error < 1e-9 at 5 sigma).
    m = noise.shape[1]
    for k in range(ret_idx.shape[0]):
        j = ret_idx[k]
        heading = ph + start_rad + inc_rad * j
        cb, sb = math.cos(heading), math.sin(heading)
        for t in range(m):
            z_hat = ranges[j] + noise[k, t, 0] * sens[0]
            d = noise[k, t, 1] * sens[1]
            cd = 1.0 - 0.5 * d * d
            sd = d - d * d * d / 6.0
            x = px + z_hat * (cb * cd - sb * sd)
            y = py + z_hat * (sb * cd + cb * sd)
            if x < x0 or x >= x1 or y < y0 or y >= y1:
                continue
            g = int(math.floor((x - x0) / cell_m)) * ny + int(math.floor((y - y0) / cell_m))
            prior = cell_sum[g] / cell_count[g] if cell_count[g] > 0 else prior_p0
            p = _logit_update(prior, _q(z_hat - ranges[j], hit_sigma, hit_ratio, free_ratio, far))
            cand_xy[n_cand, 0] = x
            cand_xy[n_cand, 1] = y
            cand_p[n_cand] = p
            cand_cell[n_cand] = g
            n_cand += 1
    for u in range(used):
        cell_count[touched[u]] = 0
    # 3. Prune, then keep the most probable points of every cell.
    used = 0
    for k in range(n_cand):
        p = cand_p[k]
        if p < prune:
            continue
        g = cand_cell[k]  # the cell steps 1 and 2 found for it
        if cell_count[g] == 0:
            touched[used] = g
            used += 1
        n = cell_count[g]
        if n < keep_per_cell:
            cell_top[g, n] = k
            cell_count[g] = n + 1
        else:  # replace the least probable kept point if this one is more probable
            worst = 0
            for e in range(1, keep_per_cell):
                if cand_p[cell_top[g, e]] < cand_p[cell_top[g, worst]]:
                    worst = e
            if p > cand_p[cell_top[g, worst]]:
                cell_top[g, worst] = k
    for u in range(used):  # mark the kept points (p + 2), then compact them forwards after the copied ones
        g = touched[u]
        for e in range(cell_count[g]):
            cand_p[cell_top[g, e]] += 2.0
        cell_count[g] = 0
    for k in range(n_cand):
        if cand_p[k] >= 2.0:
            out_xy[n_out, 0] = cand_xy[k, 0]
            out_xy[n_out, 1] = cand_xy[k, 1]
            out_p[n_out] = cand_p[k] - 2.0
            n_out += 1
    return n_out - out_lo


@njit(cache=True, parallel=True, nogil=True)
def _update_all(
    map_xy,
    map_p,
    lo,
    hi,
    poses,
    ranges,
    ret_idx,
    start_rad,
    inc_rad,
    max_range,
    noise,
    sens,
    params,
    cell_count,
    cell_sum,
    cell_top,
    touched,
    cand_cell,
    cand_xy,
    cand_p,
    out_lo,
    out_xy,
    out_p,
):
    n = poses.shape[0]
    workers = cell_count.shape[0]
    counts = np.zeros(n, dtype=np.int64)
    counter = np.zeros(1, dtype=np.int64)
    for w in prange(workers):
        while True:
            i = next_index(counter)  # the next particle not taken (gslam.workqueue)
            if i >= n:
                break
            counts[i] = _update_one(
                lo[i],
                hi[i],
                map_xy,
                map_p,
                poses[i],
                ranges,
                ret_idx,
                start_rad,
                inc_rad,
                max_range,
                noise[i],
                sens,
                params,
                cell_count[w],
                cell_sum[w],
                cell_top[w],
                touched[w],
                cand_cell[w],
                cand_xy[w],
                cand_p[w],
                out_xy,
                out_p,
                out_lo[i],
            )
    return counts


class UpdateWorkspace:
    """Per-worker cell arrays of the window (reset after each particle), grown on demand; and the buffers
    the new maps are written to, reused from one update to the one after next.

    Every update writes all the maps anew (tens of MB on a long indoor log). A fresh buffer each time is
    fresh memory from the system, paid in page faults as it is first written (docs/SPEED.md); so the
    buffer of the update before the last is written again, once
    nothing but this workspace refers to it (`release`, `take`): maps a caller still holds are never
    overwritten."""

    def __init__(self, workers: int, keep_per_cell: int) -> None:
        self.workers = max(1, int(workers))
        self.keep = max(1, keep_per_cell)
        self._alloc(0, 0)
        self._spare: tuple[np.ndarray, np.ndarray] | None = None

    def take(self, rows: int) -> tuple[np.ndarray, np.ndarray]:
        """(xy (>= rows, 2), p (>= rows,)) to write new maps to: the released buffer if it is large enough
        and unreferenced elsewhere, else a new one with room to grow."""
        if self._spare is not None:
            xy, p = self._spare
            self._spare = None
            # references: the local name and getrefcount's argument; any view of it adds one
            if len(p) >= rows and sys.getrefcount(xy) == 2 and sys.getrefcount(p) == 2:
                return xy, p
        size = int(rows * 1.25) + 1
        return np.empty((size, 2), dtype=MAP_DTYPE), np.empty(size, dtype=MAP_DTYPE)

    def release(self, xy: np.ndarray, p: np.ndarray) -> None:
        """Give back a buffer `take` returned, once the maps written to it are replaced."""
        self._spare = (xy, p)

    def _alloc(self, cells: int, points: int) -> None:
        # int32 counts and point indices: the cell arrays span the whole window (tens of MB on an outdoor
        # log with 80 m returns) and are touched at random, so their size is what the update waits on
        self.cell_count = np.zeros((self.workers, cells), dtype=np.int32)
        self.cell_sum = np.zeros((self.workers, cells))
        self.cell_top = np.zeros((self.workers, cells, self.keep), dtype=np.int32)
        self.touched = np.zeros((self.workers, points), dtype=np.int64)
        self.cand_cell = np.zeros((self.workers, points), dtype=np.int64)  # each candidate's cell
        self.cand_xy = np.zeros((self.workers, points, 2))  # the candidates: window points and new ones
        self.cand_p = np.zeros((self.workers, points))

    def reserve(self, cells: int, points: int) -> None:
        if cells > self.cell_count.shape[1] or points > self.touched.shape[1]:
            self._alloc(
                max(int(cells * 1.25) + 1, self.cell_count.shape[1]),
                max(int(points * 1.25) + 1, self.touched.shape[1]),
            )


def window_cells(
    poses: np.ndarray, ranges_m: np.ndarray, bearings_rad: np.ndarray, margin_m: float, cell_m: float
) -> int:
    """The most cells any particle's window spans (the box of its pose and its returns' end points, grown
    by `margin_m`, as `_update_one` lays it out), plus one row and column either way for rounding: the
    size of the cell arrays. A scan seen over half a turn fills half the square of twice its range."""
    if len(poses) == 0:
        return 1
    ranges_m = np.asarray(ranges_m, dtype=float)
    ends = np.column_stack([ranges_m * np.cos(bearings_rad), ranges_m * np.sin(bearings_rad)])  # sensor frame
    # The kernel places the end points with its own rounding (a cosine of heading plus bearing): the ulps
    # between the two are far inside the row and column of slack either way.
    x0, y0, x1, y1 = window_boxes(poses, ends, margin_m)
    nx = np.floor((x1 - x0) / cell_m) + 4  # the kernel aligns x0 down to a cell edge: at most one more
    ny = np.floor((y1 - y0) / cell_m) + 4
    return int((nx * ny).max())


def update_maps(
    map_xy: np.ndarray,
    map_p: np.ndarray,
    map_lo: np.ndarray,
    map_hi: np.ndarray,
    poses: np.ndarray,
    ranges_m: np.ndarray,
    returns: np.ndarray,
    start_angle_rad: float,
    angle_increment_rad: float,
    max_range_m: float,
    noise: np.ndarray,
    *,
    range_sigma_m: float,
    bearing_sigma_rad: float,
    hit_sigma_m: float,
    hit_ratio: float,
    free_ratio: float,
    prune_threshold: float,
    cell_size_m: float,
    prior_p0: float,
    max_points_per_cell: int,
    workspace: UpdateWorkspace,
    no_return_free_m: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 2 to 4 for every particle (see the module docstring).

    `ranges_m` (B,) are the occlusion ranges of the scan (the maximum range where a beam saw nothing),
    `returns` (B,) the beams that returned an observation; a beam that saw nothing observes free space up
    to `no_return_free_m` (None: the maximum range); `noise` (N, R, M, 2) standard normal draws
    for the M new points around each of the R returns (range, bearing). Returns (xy, p, bounds) of the
    new maps: particle i's map is xy[bounds[i, 0]:bounds[i, 1]]. xy and p come from `workspace.take`
    (and may be longer than the maps in them): give them back with `workspace.release` when the maps in
    them are no longer used.
    """
    n = len(poses)
    ret_idx = np.flatnonzero(returns).astype(np.int64)
    sizes = np.asarray(map_hi - map_lo, dtype=np.int64)
    new = len(ret_idx) * noise.shape[2]
    # Particle i writes its copied points, then the candidates it keeps: at most its map + its new points.
    out_lo = np.concatenate([[0], np.cumsum(sizes + new)]).astype(np.int64)
    workspace.reserve(
        window_cells(
            poses, ranges_m[ret_idx], start_angle_rad + angle_increment_rad * ret_idx, 3 * hit_sigma_m, cell_size_m
        ),
        int(sizes.max() if n else 0) + new,
    )
    params = np.array(
        [
            hit_sigma_m,
            hit_ratio,
            free_ratio,
            prune_threshold,
            cell_size_m,
            prior_p0,
            3 * hit_sigma_m,
            max_points_per_cell,
            far_z2(hit_ratio, free_ratio),
            max_range_m if no_return_free_m is None else min(float(no_return_free_m), max_range_m),
        ]
    )
    out_xy, out_p = workspace.take(int(out_lo[-1]))
    counts = _update_all(
        np.ascontiguousarray(map_xy, dtype=MAP_DTYPE),
        np.ascontiguousarray(map_p, dtype=MAP_DTYPE),
        np.asarray(map_lo, dtype=np.int64),
        np.asarray(map_hi, dtype=np.int64),
        np.ascontiguousarray(poses, dtype=float),
        np.ascontiguousarray(ranges_m, dtype=float),
        ret_idx,
        float(start_angle_rad),
        float(angle_increment_rad),
        float(max_range_m),
        np.ascontiguousarray(noise),
        np.array([range_sigma_m, bearing_sigma_rad]),
        params,
        workspace.cell_count,
        workspace.cell_sum,
        workspace.cell_top,
        workspace.touched,
        workspace.cand_cell,
        workspace.cand_xy,
        workspace.cand_p,
        out_lo,
        out_xy,
        out_p,
    )
    return out_xy, out_p, np.column_stack([out_lo[:-1], out_lo[:-1] + counts])


# --- which settings this implementation covers ---------------------------------------------------------
REQUIRED: dict[str, Any] = {
    "map_update": "binary",
    "observation_unit": "beam",
    "prior_interpolation": "cell_mean",
    "free_space_beams": 0,
    "prune_relative": False,
    "weighting": "matched_field",
}
"""The reading of the open points the kernel implements: any other value of these runs `wholemap`. The
weight must be the matcher's ("matched_field"): the other weights are computed from q and p inside the
numpy steps."""
KERNEL_OPTIONS = (
    "range_sigma_m",
    "bearing_sigma_rad",
    "hit_sigma_m",
    "hit_ratio",
    "free_ratio",
    "prune_threshold",
    "cell_size_m",
    "prior_p0",
    "max_points_per_cell",
    "no_return_free_m",
)
"""The settings the kernel takes as its parameters (`update_maps`)."""
OPTIONS = (*KERNEL_OPTIONS, "points_per_observation", "weight_gain", "particles")
"""Every setting this implementation reads; a setting outside these and `REQUIRED` does not reach it."""


def supports(cfg: FilterConfig) -> bool:
    """Whether the compiled kernel implements cfg's reading of the open points (`REQUIRED`, and density
    control on: at least one point kept per cell)."""
    return all(getattr(cfg, k) == v for k, v in REQUIRED.items()) and cfg.max_points_per_cell >= 1


def options(cfg: FilterConfig) -> dict[str, Any]:
    """The settings of cfg this implementation reads (`OPTIONS`)."""
    return {k: getattr(cfg, k) for k in OPTIONS}


def kernel_options(cfg: FilterConfig) -> dict[str, Any]:
    """The keyword arguments of `update_maps` taken from cfg."""
    return {k: getattr(cfg, k) for k in KERNEL_OPTIONS}


class WindowedUpdate:
    """Steps 2 to 4 (and the step's weight from the matcher) with the compiled kernel, for a filter whose
    settings this implementation `supports`."""

    def __init__(self, cfg: FilterConfig, threads: int) -> None:
        if not supports(cfg):
            raise ValueError("the compiled map update does not implement these settings; use gslam.mapupdate.select")
        self.cfg = cfg
        self.workspace = UpdateWorkspace(threads, cfg.max_points_per_cell)
        self.noise = NoiseDraws(threads)

    def __call__(
        self,
        maps: list[PointMap],
        layout: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        poses: np.ndarray,
        scan: Scan,
        rng: np.random.Generator,
        matched_log_like: np.ndarray,
    ) -> tuple[list[PointMap], tuple[np.ndarray, ...] | None, np.ndarray, int]:
        """(new maps, their layout (xy, p, lo, hi) in one buffer, the step's log-likelihoods, points in all
        maps). `layout` is the maps' current layout (`gslam.pointmap.distinct_maps`)."""
        cfg, n = self.cfg, len(poses)
        xy, p, lo, hi = layout
        log_like = matched_log_like / (cfg.weight_gain * n) if len(p) else np.zeros(n)
        returns = scan.returns
        noise = self.noise.draw(rng, (n, int(returns.sum()), cfg.points_per_observation, 2))
        geom = scan.geometry
        out_xy, out_p, bounds = update_maps(
            xy,
            p,
            lo,
            hi,
            poses,
            scan.occlusion_ranges_m,
            returns,
            geom.start_angle_rad,
            geom.angle_increment_rad,
            geom.max_range_m,
            noise,
            workspace=self.workspace,
            **kernel_options(cfg),
        )
        new_maps = [PointMap(out_xy[a:b], out_p[a:b]) for a, b in bounds.tolist()]  # int slices: 2x faster
        new_layout = (out_xy, out_p, bounds[:, 0].copy(), bounds[:, 1].copy())
        self.workspace.release(xy, p)  # the maps before this update: written to again when free
        return new_maps, new_layout, log_like, int((bounds[:, 1] - bounds[:, 0]).sum())
