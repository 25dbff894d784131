"""Loop closure: a scan matched against a submap far back in time by branch and bound, then refined.

A submap is a few consecutive nodes' scans drawn in the frame of its first node, as a likelihood field:
each cell holds exp(-d^2 / 2 sigma^2), d the distance from the cell's centre to the mean of the returns in
the nearest occupied cell (the returns' own positions, not their cells': a wall keeps its place). A scan is
matched against it over a whole window of poses (`window_m`, `window_rad` around the estimate) by the
branch and bound of Hess et al. (2016, "Real-time loop closure in 2D LIDAR SLAM", Algorithm 3): for every
heading on a grid, the translations are searched coarse to fine, each coarse candidate scored by an upper
bound (the field's maximum over the 2^h x 2^h cells it stands for, precomputed as a pyramid), and a branch
is cut as soon as its bound cannot beat the best score found. The result is the best pose on the window's
grid, exactly, at the cost of a local search. It is then refined off the grid by Gauss-Newton on the
field, bilinearly interpolated.

The score is the mean field value over the scan's returns (0 to 1); a match is a candidate closure when
it reaches `min_score`. The back end (`gslam.backend`) decides whether it is kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage


@dataclass(frozen=True)
class ClosureSettings:
    """How loop closures are searched and when a match counts."""

    cell_m: float = 0.05
    """The submaps' cell: the finest step of the search."""
    sigma_m: float = 0.05
    """Width of the likelihood field around each return."""
    max_range_m: float = 20.0
    """Returns further than this are left out of submaps and matched scans (far returns are sparse
    and amplify heading errors)."""
    voxel_m: float = 0.1
    """A matched scan keeps one return per voxel of this size (an even spread, fewer points)."""
    window_m: float = 3.0
    """Half-width of the translations searched around the estimate."""
    window_rad: float = 0.35
    """Half-width of the headings searched (20 degrees)."""
    heading_range_m: float = 10.0
    """The headings are searched in steps that move a return at this range by one cell (Hess et al.: at the
    furthest return); the refinement then finds the heading between the steps."""
    levels: int = 6
    """Coarse levels of the pyramid: the coarsest candidate covers 2^levels cells."""
    min_score: float = 0.55
    """A match scoring less (mean field value over the returns) is not a closure."""
    ambiguity_m: float = 1.0
    ambiguity_ratio: float = 0.9
    """A match is ambiguous, and not a closure, when a pose at least `ambiguity_m` from it in the window
    scores `ambiguity_ratio` of its score or more: along a corridor, or among repeated features, the
    best score is as likely to be a neighbour of the right place as the place."""


@dataclass
class Submap:
    """A likelihood field in the frame of its first node, with its max pyramid for the search."""

    origin_xy: np.ndarray  # (2,) the corner of cell (0, 0), in the submap's frame
    pyramid: np.ndarray  # (levels + 1, nx, ny) float32; [h][i, j] = max of level 0 over [i, i+2^h) x [j, j+2^h)
    cell_m: float

    @classmethod
    def build(cls, points_xy: np.ndarray, settings: ClosureSettings) -> Submap:
        """The field of `points_xy` (K, 2, the returns in the submap's frame)."""
        cell = settings.cell_m
        margin = 4.0 * settings.sigma_m + cell
        lo = points_xy.min(axis=0) - margin
        hi = points_xy.max(axis=0) + margin
        shape = np.ceil((hi - lo) / cell).astype(int) + 1
        ij = np.floor((points_xy - lo) / cell).astype(int)
        # each occupied cell's mean point: the field measures from the returns themselves, not from cell
        # centres (a wall would otherwise be moved to its cells' centres, up to half a cell)
        flat = ij[:, 0] * shape[1] + ij[:, 1]
        count = np.bincount(flat, minlength=shape[0] * shape[1])
        mean_x = np.bincount(flat, weights=points_xy[:, 0], minlength=len(count))
        mean_y = np.bincount(flat, weights=points_xy[:, 1], minlength=len(count))
        hit = count > 0
        mean_x[hit] /= count[hit]
        mean_y[hit] /= count[hit]
        # True where there is no return (the EDT's features are the zeros); the nearest occupied cell's index
        _, (ni, nj) = ndimage.distance_transform_edt(~hit.reshape(shape), return_indices=True)
        nearest = ni * shape[1] + nj
        cx = lo[0] + (np.arange(shape[0])[:, None] + 0.5) * cell
        cy = lo[1] + (np.arange(shape[1])[None, :] + 0.5) * cell
        d2 = (cx - mean_x[nearest]) ** 2 + (cy - mean_y[nearest]) ** 2
        field = np.exp(-d2 / (2 * settings.sigma_m**2)).astype(np.float32)
        field[field < 1e-3] = 0.0
        return cls(lo, _pyramid(field, settings.levels), cell)


def _pyramid(field: np.ndarray, levels: int) -> np.ndarray:
    out = np.zeros((levels + 1, *field.shape), dtype=np.float32)
    out[0] = field
    for h in range(1, levels + 1):
        prev, half = out[h - 1], 1 << (h - 1)
        cur = prev.copy()
        cur[:-half, :] = np.maximum(cur[:-half, :], prev[half:, :])
        cur2 = cur.copy()
        cur2[:, :-half] = np.maximum(cur2[:, :-half], cur[:, half:])
        out[h] = cur2
    return out


def voxel_filter(points_xy: np.ndarray, voxel_m: float) -> np.ndarray:
    """One point per occupied voxel (the first), in the order given."""
    if len(points_xy) == 0:
        return points_xy
    keys = np.floor(points_xy / voxel_m).astype(np.int64)
    _, first = np.unique(keys[:, 0] * 1_000_003 + keys[:, 1], return_index=True)
    return points_xy[np.sort(first)]


@dataclass
class Match:
    """A scan's best pose in a submap's frame and its score (mean field value over the returns); the best
    score at least `ambiguity_m` away from it, when one reaches `ambiguity_ratio` of it."""

    pose: np.ndarray
    score: float
    rival: float | None = None

    @property
    def ambiguous(self) -> bool:
        return self.rival is not None


def match_scan(submap: Submap, points_xy: np.ndarray, estimate: np.ndarray, settings: ClosureSettings) -> Match | None:
    """The best pose of the scan (`points_xy`, in the sensor frame) in the submap within the window around
    `estimate` (a pose in the submap's frame), refined; None when nothing reaches `min_score`."""
    if len(points_xy) < 10:
        return None
    r_max = min(float(np.max(np.hypot(points_xy[:, 0], points_xy[:, 1]))), settings.heading_range_m)
    # the heading step that moves a return at r_max by about one cell (Hess et al. 2016, eq. 7)
    step = math.acos(max(-1.0, 1.0 - submap.cell_m**2 / (2.0 * max(r_max, submap.cell_m) ** 2)))
    n_half = int(math.ceil(settings.window_rad / step))
    headings = estimate[2] + step * np.arange(-n_half, n_half + 1)
    w = int(math.ceil(settings.window_m / submap.cell_m))
    args = (submap.pyramid, submap.origin_xy[0], submap.origin_xy[1], submap.cell_m, points_xy, headings,
            float(estimate[0]), float(estimate[1]), w)  # fmt: skip
    score, a, dx, dy = _branch_and_bound(*args, settings.min_score, 0, 0, -1.0)
    if a < 0:
        return None
    # the best pose away from this one: the same search with the disc around it cut out
    apart = settings.ambiguity_m / submap.cell_m
    floor = max(settings.min_score, settings.ambiguity_ratio * score)
    rival, b, _, _ = _branch_and_bound(*args, floor, dx, dy, apart)
    pose = np.array([estimate[0] + dx * submap.cell_m, estimate[1] + dy * submap.cell_m, headings[a]])
    field = (submap.pyramid[0], submap.origin_xy[0], submap.origin_xy[1], submap.cell_m, points_xy)
    refined = _refine(*field, pose)
    other = float(rival) if b >= 0 else None
    # the search scores a return by its cell's value, the refinement between cell centres: the two poses
    # are compared on the refinement's interpolated field, the score stays the search's
    near = np.hypot(*(refined[:2] - pose[:2])) < 2 * submap.cell_m
    if near and _mean_field(*field, refined) >= _mean_field(*field, pose):
        return Match(refined, float(score), other)
    return Match(pose, float(score), other)


@njit(cache=True, nogil=True)
def _lookup(pyr, h, i, j):  # pragma: no cover - compiled
    """An upper bound of the field over cells [i, i+2^h) x [j, j+2^h) (exact at h = 0); 0 outside."""
    nx, ny = pyr.shape[1], pyr.shape[2]
    size = 1 << h
    if i >= nx or j >= ny or i + size <= 0 or j + size <= 0:
        return 0.0
    if i < 0:
        i = 0  # the window's part inside starts at 0: the max from 0 over 2^h cells bounds it
    if j < 0:
        j = 0
    return pyr[h, i, j]


@njit(cache=True, nogil=True)
def _score_at(pyr, h, ci, cj, a, dx, dy):  # pragma: no cover - compiled
    k = ci.shape[1]
    total = 0.0
    for m in range(k):
        total += _lookup(pyr, h, ci[a, m] + dx, cj[a, m] + dy)
    return total / k


@njit(cache=True, nogil=True)
def _branch_and_bound(
    pyr, ox, oy, cell, pts, headings, ex, ey, w, min_score, cut_x, cut_y, cut_r
):  # pragma: no cover - compiled
    """Hess et al. (2016) Algorithm 3 over headings x translations [-w, w]^2 cells: (score, heading index,
    dx, dy) of the best candidate scoring at least min_score; heading index -1 when none does. With
    cut_r >= 0, translations within cut_r cells of (cut_x, cut_y) are left out (whole branches inside it
    are cut)."""
    n_a = len(headings)
    k = pts.shape[0]
    ci = np.empty((n_a, k), dtype=np.int64)
    cj = np.empty((n_a, k), dtype=np.int64)
    for a in range(n_a):
        c, s = math.cos(headings[a]), math.sin(headings[a])
        for m in range(k):
            x = ex + c * pts[m, 0] - s * pts[m, 1]
            y = ey + s * pts[m, 0] + c * pts[m, 1]
            ci[a, m] = int(math.floor((x - ox) / cell))
            cj[a, m] = int(math.floor((y - oy) / cell))
    top = pyr.shape[0] - 1
    size = 1 << top
    n_side = (2 * w) // size + 1
    n_top = n_a * n_side * n_side
    cap = n_top + 8 * (top + 2)
    st_a = np.empty(cap, dtype=np.int64)
    st_x = np.empty(cap, dtype=np.int64)
    st_y = np.empty(cap, dtype=np.int64)
    st_h = np.empty(cap, dtype=np.int64)
    st_s = np.empty(cap, dtype=np.float64)
    # the coarsest candidates, pushed in increasing score so that the best is popped first
    scores = np.empty(n_top)
    ca = np.empty(n_top, dtype=np.int64)
    cx = np.empty(n_top, dtype=np.int64)
    cy = np.empty(n_top, dtype=np.int64)
    q = 0
    for a in range(n_a):
        for u in range(n_side):
            for v in range(n_side):
                dx = -w + u * size
                dy = -w + v * size
                ca[q], cx[q], cy[q] = a, dx, dy
                scores[q] = _score_at(pyr, top, ci, cj, a, dx, dy)
                q += 1
    order = np.argsort(scores)
    n = 0
    for r in range(n_top):
        o = order[r]
        if scores[o] < min_score:
            continue
        st_a[n], st_x[n], st_y[n], st_h[n], st_s[n] = ca[o], cx[o], cy[o], top, scores[o]
        n += 1
    best, best_a, best_x, best_y = min_score, -1, 0, 0
    child_s = np.empty(4)
    child_x = np.empty(4, dtype=np.int64)
    child_y = np.empty(4, dtype=np.int64)
    while n > 0:
        n -= 1
        a, dx, dy, h, sc = st_a[n], st_x[n], st_y[n], st_h[n], st_s[n]
        if sc <= best and best_a >= 0 or sc < best:
            continue
        if cut_r >= 0.0 and _inside(dx, dy, 1 << h, cut_x, cut_y, cut_r):
            continue
        if h == 0:
            best, best_a, best_x, best_y = sc, a, dx, dy
            continue
        half = 1 << (h - 1)
        m = 0
        for ox_ in range(2):
            for oy_ in range(2):
                x = dx + ox_ * half
                y = dy + oy_ * half
                if x > w or y > w:
                    continue
                child_x[m], child_y[m] = x, y
                child_s[m] = _score_at(pyr, h - 1, ci, cj, a, x, y)
                m += 1
        # push the children worst first, so the best is explored next
        for _ in range(m):
            lo_i, lo_s = -1, 2.0
            for t in range(m):
                if child_s[t] < lo_s:
                    lo_i, lo_s = t, child_s[t]
            if lo_s > best or (lo_s >= best and best_a < 0):
                st_a[n], st_x[n], st_y[n], st_h[n], st_s[n] = a, child_x[lo_i], child_y[lo_i], h - 1, lo_s
                n += 1
            child_s[lo_i] = 3.0  # taken
    return best, best_a, best_x, best_y


@njit(cache=True, nogil=True)
def _inside(dx, dy, size, cx, cy, r):  # pragma: no cover - compiled
    """Whether every translation of the square [dx, dx + size) x [dy, dy + size) lies within r of (cx, cy)."""
    fx = max(abs(dx - cx), abs(dx + size - 1 - cx))
    fy = max(abs(dy - cy), abs(dy + size - 1 - cy))
    return fx * fx + fy * fy < r * r


@njit(cache=True, nogil=True)
def _bilinear(field, ox, oy, cell, x, y):  # pragma: no cover - compiled
    """Field value and gradient (per metre) at (x, y), bilinear between cell centres; 0 outside."""
    u = (x - ox) / cell - 0.5
    v = (y - oy) / cell - 0.5
    i = int(math.floor(u))
    j = int(math.floor(v))
    if i < 0 or j < 0 or i + 1 >= field.shape[0] or j + 1 >= field.shape[1]:
        return 0.0, 0.0, 0.0
    fu, fv = u - i, v - j
    f00, f10, f01, f11 = field[i, j], field[i + 1, j], field[i, j + 1], field[i + 1, j + 1]
    val = f00 * (1 - fu) * (1 - fv) + f10 * fu * (1 - fv) + f01 * (1 - fu) * fv + f11 * fu * fv
    gu = ((f10 - f00) * (1 - fv) + (f11 - f01) * fv) / cell
    gv = ((f01 - f00) * (1 - fu) + (f11 - f10) * fu) / cell
    return val, gu, gv


@njit(cache=True, nogil=True)
def _mean_field(field, ox, oy, cell, pts, pose):  # pragma: no cover - compiled
    c, s = math.cos(pose[2]), math.sin(pose[2])
    total = 0.0
    for m in range(pts.shape[0]):
        x = pose[0] + c * pts[m, 0] - s * pts[m, 1]
        y = pose[1] + s * pts[m, 0] + c * pts[m, 1]
        total += _bilinear(field, ox, oy, cell, x, y)[0]
    return total / pts.shape[0]


@njit(cache=True, nogil=True)
def _refine(field, ox, oy, cell, pts, pose0):  # pragma: no cover - compiled
    """Gauss-Newton on sum (1 - field(T p))^2 from pose0, at most 10 steps, each at most one cell."""
    pose = pose0.copy()
    for _ in range(10):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        h = np.zeros((3, 3))
        g = np.zeros(3)
        for m in range(pts.shape[0]):
            rx = c * pts[m, 0] - s * pts[m, 1]
            ry = s * pts[m, 0] + c * pts[m, 1]
            val, gx, gy = _bilinear(field, ox, oy, cell, pose[0] + rx, pose[1] + ry)
            if val <= 0.0:
                continue
            r = 1.0 - val
            jx, jy, jt = -gx, -gy, -(gx * -ry + gy * rx)
            h[0, 0] += jx * jx
            h[0, 1] += jx * jy
            h[0, 2] += jx * jt
            h[1, 1] += jy * jy
            h[1, 2] += jy * jt
            h[2, 2] += jt * jt
            g[0] += jx * r
            g[1] += jy * r
            g[2] += jt * r
        h[1, 0], h[2, 0], h[2, 1] = h[0, 1], h[0, 2], h[1, 2]
        for d in range(3):
            h[d, d] += 1e-6 + 1e-3 * h[d, d]
        delta = -np.linalg.solve(h, g)
        norm = math.hypot(delta[0], delta[1])
        if norm > cell:
            delta *= cell / norm
        pose += delta
        if norm < 1e-4 and abs(delta[2]) < 1e-5:
            break
    return pose
