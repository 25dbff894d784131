"""Scan matching and observation likelihood on each particle's point map (open points 4 and 6), compiled.

GMapping's scan matcher (Grisetti, Stachniss & Burgard 2007; openslam_gmapping `ScanMatcher::optimize`,
`score`, `likelihoodAndScore`), carried over from its occupancy grid to G-SLAM's point map:

- For each particle, the map points with probability p >= `min_p` that lie in a window around the scan
  (its end points' box at the particle's motion sample, plus a margin) are rasterised into a fine grid
  (`cell_m`); each occupied cell keeps the mean of its points, as GMapping's cells keep the mean of
  their hits. The window is local to the scan, so the work does not grow with the map.
- The score of a pose is sum_j exp(-d_j^2 / 2 sigma_j^2), d_j the distance from return j's end point to
  the map among the (2k+1)^2 cells around it (k = `kernel`). GMapping also skips a cell whose neighbour
  one cell back along the beam is occupied (a wall's far side); on a point map that matches only the
  front of the spread of a surface's points, which put every pose a few centimetres back along its
  heading (docs/CHOICES.md), so every occupied cell counts. When the two nearest
  cell means lie within `line_pair_m` of each other (neighbouring samples of one surface), d_j is the
  distance across the line through them (point to line, as PL-ICP, Censi 2008); otherwise it is the
  distance to the nearest mean. A point-to-line distance does not depend on where the return falls
  between the map's samples; a point-to-point one does, so those returns may be scored with a width
  that grows with range, sigma_j^2 = sigma_s^2 + (r_j sigma_a)^2 (the map samples a surface at range r
  every r x the angle between beams); line returns are scored with sigma_s.
- The pose climbs that score from the motion sample: one step forwards and backwards in x, y and phi,
  move to the best while it improves, halve the steps when it does not, `levels` times.
- A second start, coarse to fine, for the particles whose climb fits clearly worse than the best one's
  (`coarse_gate`): the same climb from the motion sample down a pyramid of coarser rasters, then on the
  fine one, kept when it explains clearly more of the returns (`_coarse_start_one`). The particles are
  climbed first, all of them, then the second start runs for the ones the gate picks.
- The log-likelihood of the scan at the matched pose is sum_j -d_j^2 / 2 sigma_l^2, with d_j = `miss_m`
  for a return that finds no occupied cell near it (GMapping's `nullLikelihood`).

Every particle is independent: the particles are spread over `threads` workers (numba prange), each
with its own raster, so the result does not depend on the number of threads.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import njit, prange

from gslam.fastmath import fast_exp
from gslam.pointmap import MAP_DTYPE
from gslam.scan import window_boxes
from gslam.workqueue import next_index

if TYPE_CHECKING:
    from gslam.config import FilterConfig

_EMPTY = -1
POLISH_TOLERANCE = 1e-4
"""The Gauss-Newton finish stops when a step is below this (m and rad)."""


@njit(cache=True, inline="always")
def _nearer(ex, ey, k, mean_xy, best, second, k1, k2):
    """The two nearest cell means so far (squared distances best <= second, cells k1, k2; -1: none yet),
    updated with cell k's mean."""
    dx = ex - mean_xy[k, 0]
    dy = ey - mean_xy[k, 1]
    d2 = dx * dx + dy * dy
    if best < 0.0 or d2 < best:
        return d2, best, k, k1
    if second < 0.0 or d2 < second:
        return best, d2, k1, k
    return best, second, k1, k2


@njit(cache=True, inline="always")
def _search_interior(ex, ey, cx, cy, ny, kernel, grid, mean_xy):
    """`_nearest_two`'s search where every cell searched lies in the raster."""
    best = -1.0
    second = -1.0
    k1 = 0
    k2 = 0
    for ix in range(cx - kernel, cx + kernel + 1):
        row = ix * ny
        for iy in range(cy - kernel, cy + kernel + 1):
            k = grid[row + iy]
            if k == _EMPTY:
                continue
            best, second, k1, k2 = _nearer(ex, ey, k, mean_xy, best, second, k1, k2)
    return best, second, k1, k2


@njit(cache=True, inline="always")
def _nearest_two(ex, ey, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy):
    """The two nearest cell means to (ex, ey) among the (2 kernel + 1)^2 cells around it: (best, second,
    k1, k2), squared distances best <= second of cells k1, k2; -1 for none found."""
    inv = 1.0 / cell_m  # hoisted out of the loops by the compiler: a multiplication per return, not a division
    cx = int(math.floor((ex - x0) * inv))
    cy = int(math.floor((ey - y0) * inv))
    if kernel <= cx < nx - kernel and kernel <= cy < ny - kernel:
        # every cell searched lies in the raster: the same cells in the same order as below, without the
        # bounds tests
        if kernel == 1:  # the default, as a constant: the compiler unrolls the 3 x 3 cells (5 % of the matcher)
            return _search_interior(ex, ey, cx, cy, ny, 1, grid, mean_xy)
        return _search_interior(ex, ey, cx, cy, ny, kernel, grid, mean_xy)
    best = -1.0
    second = -1.0
    k1 = 0
    k2 = 0
    for ix in range(cx - kernel, cx + kernel + 1):
        if ix < 0 or ix >= nx:
            continue
        for iy in range(cy - kernel, cy + kernel + 1):
            if iy < 0 or iy >= ny:
                continue
            k = grid[ix * ny + iy]
            if k == _EMPTY:
                continue
            best, second, k1, k2 = _nearer(ex, ey, k, mean_xy, best, second, k1, k2)
    return best, second, k1, k2


@njit(cache=True, inline="always")
def _surface_line(second, k1, k2, mean_xy, pair_d2):
    """(tx, ty, t2): the direction from cell mean k1 to k2 and its squared length, when a return is scored
    point to line: the two nearest means, when close enough to be neighbouring samples of one surface
    (within sqrt(pair_d2)), define its local direction and the distance is taken across it (PL-ICP, Censi
    2008). t2 = 0: scored point to point (no second mean, pairs off, or the two too far apart)."""
    if pair_d2 > 0.0 and second >= 0.0:
        tx = mean_xy[k2, 0] - mean_xy[k1, 0]
        ty = mean_xy[k2, 1] - mean_xy[k1, 1]
        t2 = tx * tx + ty * ty
        if 0.0 < t2 <= pair_d2:
            return tx, ty, t2
    return 0.0, 0.0, 0.0


@njit(cache=True, inline="always")
def _across_d2(ex, ey, k1, tx, ty, t2, mean_xy):
    """Squared distance from (ex, ey) across the line through cell mean k1 with direction (tx, ty), t2 its
    squared length (`_surface_line`)."""
    cross = (ex - mean_xy[k1, 0]) * ty - (ey - mean_xy[k1, 1]) * tx
    return cross * cross / t2


@njit(cache=True, inline="always")
def _best_d2(ex, ey, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, pair_d2):
    """(squared distance from (ex, ey) to the map, True when it is taken across the line through the two
    nearest cell means) or (-1, False) when no occupied cell is found."""
    best, second, k1, k2 = _nearest_two(ex, ey, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy)
    tx, ty, t2 = _surface_line(second, k1, k2, mean_xy, pair_d2)
    if t2 > 0.0:
        return _across_d2(ex, ey, k1, tx, ty, t2, mean_xy), True
    return best, False


@njit(cache=True, inline="always")
def _return_d2(pose, c, s, ends, j, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, pair_d2):
    """_best_d2 of return j (end point in the sensor frame) seen from `pose`
    (c, s: cos and sin of its heading)."""
    lx, ly = ends[j, 0], ends[j, 1]
    ex = pose[0] + c * lx - s * ly
    ey = pose[1] + s * lx + c * ly
    return _best_d2(ex, ey, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, pair_d2)


@njit(cache=True)
def _score(pose, ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, inv_2s2, pair_d2, inv_line, beat):
    """Sum over returns j of exp(-d_j^2 w_j), w_j = inv_line for a point-to-line distance, else inv_2s2[j]
    (1 / 2 sigma_j^2 of return j).

    A candidate of the climb only matters if it scores above `beat`: every term is at most 1, so once the
    sum so far plus one per return left stays below `beat` (by 1e-9, far above the sum's rounding), the
    rest is not computed and -1 is returned. `beat` -inf computes the whole sum."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    total = 0.0
    count = ends.shape[0]
    bound = beat - 1e-9
    for j in range(count):
        if total + (count - j) < bound:
            return -1.0  # cannot reach `beat`
        d2, line = _return_d2(pose, c, s, ends, j, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, pair_d2)
        if d2 >= 0.0:
            total += fast_exp(-d2 * (inv_line if line else inv_2s2[j]))
    return total


@njit(cache=True, inline="always")
def _add_point(x, y, g, grid, sums, touched, used):
    """Add the point (x, y) to raster cell g (its slot claimed and zeroed on first use); returns the number
    of occupied cells."""
    slot = grid[g]
    if slot == _EMPTY:
        slot = used
        grid[g] = slot
        touched[slot] = g
        sums[slot, 0] = 0.0
        sums[slot, 1] = 0.0
        sums[slot, 2] = 0.0
        used += 1
    sums[slot, 0] += x
    sums[slot, 1] += y
    sums[slot, 2] += 1.0
    return used


@njit(cache=True, inline="always")
def _to_means(sums, used):
    """sums[slot, :2] from the sums of a cell's points to their mean."""
    for slot in range(used):
        sums[slot, 0] /= sums[slot, 2]
        sums[slot, 1] /= sums[slot, 2]


@njit(cache=True, inline="always")
def _rasterise_range(map_xy, map_p, lo, hi, min_p, x0, y0, nx, ny, cell_m, grid, sums, touched, used):
    """Add the points lo:hi with p >= min_p inside the window to `grid` (slot per occupied cell, -1 empty)
    and their coordinates to sums[slot]; `used` cells occupied before, returns those after."""
    inv = 1.0 / cell_m  # a multiplication per point, as `_nearest_two`'s
    for k in range(lo, hi):
        if map_p[k] < min_p:
            continue
        cx = int(math.floor((map_xy[k, 0] - x0) * inv))
        cy = int(math.floor((map_xy[k, 1] - y0) * inv))
        if cx < 0 or cx >= nx or cy < 0 or cy >= ny:
            continue
        used = _add_point(map_xy[k, 0], map_xy[k, 1], cx * ny + cy, grid, sums, touched, used)
    return used


@njit(cache=True, inline="always")
def _rasterise(map_xy, map_p, lo, hi, min_p, x0, y0, nx, ny, cell_m, grid, sums, touched):
    """Rasterise the points lo:hi with p >= min_p inside the window into `grid` (slot per occupied cell,
    -1 empty); sums[slot, :2] ends as the mean of the cell's points. Returns the occupied cells."""
    used = _rasterise_range(map_xy, map_p, lo, hi, min_p, x0, y0, nx, ny, cell_m, grid, sums, touched, 0)
    _to_means(sums, used)
    return used


@njit(cache=True, inline="always")
def _level_shape(nx, ny, factor, level):
    """(factor of, columns, rows) of pyramid level `level` (0: `factor` times coarser than the fine raster,
    1: factor^2, ...) over a fine window of nx x ny cells, same origin."""
    fl = factor ** (level + 1)
    return fl, nx // fl + 1, ny // fl + 1


@njit(cache=True, inline="always")
def _rasterise_pyramid(
    map_xy, map_p, lo, hi, min_p, x0, y0, nx, ny, cell_m, grid, sums, touched, factor, cgrid, csums, ctouched,
    cused, base,
):  # fmt: skip
    """`_rasterise` into the fine raster and, in the same pass over the map, into each level of the
    pyramid above it (level l: factor^(l+1) times coarser, its cells at offset base[l] of `cgrid`, its
    slots in csums[l], ctouched[l]; cused[l] gets its occupied cells, base[l] its offset). Returns the fine
    cells occupied. A point in the window is in every level, so every level is occupied or none."""
    depth = csums.shape[0]
    rows = np.zeros(depth, dtype=np.int64)
    fls = np.zeros(depth, dtype=np.int64)
    offset = 0
    for lv in range(depth):
        fl, cnx, cny = _level_shape(nx, ny, factor, lv)
        base[lv], rows[lv], fls[lv] = offset, cny, fl
        offset += cnx * cny
        cused[lv] = 0
    used = 0
    inv = 1.0 / cell_m  # a multiplication per point, as `_nearest_two`'s
    for k in range(lo, hi):
        if map_p[k] < min_p:
            continue
        cx = int(math.floor((map_xy[k, 0] - x0) * inv))
        cy = int(math.floor((map_xy[k, 1] - y0) * inv))
        if cx < 0 or cx >= nx or cy < 0 or cy >= ny:
            continue
        used = _add_point(map_xy[k, 0], map_xy[k, 1], cx * ny + cy, grid, sums, touched, used)
        for lv in range(depth):
            g = base[lv] + (cx // fls[lv]) * rows[lv] + cy // fls[lv]
            cused[lv] = _add_point(map_xy[k, 0], map_xy[k, 1], g, cgrid, csums[lv], ctouched[lv], cused[lv])
    _to_means(sums, used)
    for lv in range(depth):
        _to_means(csums[lv], cused[lv])
    return used


@njit(cache=True, inline="always")
def _scored(cand, seen_pose, seen):
    """The index of `cand` among the first `seen` poses the climb scored (exactly equal), or -1."""
    for e in range(seen):
        if seen_pose[e, 0] == cand[0] and seen_pose[e, 1] == cand[1] and seen_pose[e, 2] == cand[2]:
            return e
    return -1


@njit(cache=True)
def _climb(
    pose,
    ends,
    x0,
    y0,
    nx,
    ny,
    cell_m,
    kernel,
    grid,
    mean_xy,
    score_inv,
    pair_d2,
    inv_line,
    step_xy,
    step_phi,
    levels,
    max_iter,
):
    """Hill-climb `pose` (in place) on the score: one step forwards and backwards in x, y and phi, move to
    the best while it improves, halve the steps when it does not, `levels` times (GMapping's
    `ScanMatcher::optimize`). Returns the score at the final pose.

    A pose the climb has scored before is not scored again: the way back to the pose just left, a
    neighbour of an earlier pose (a move in x then y then back in x), a step of an earlier level reached
    by two of the next. Each scored pose's result is kept (the score, or -1 where it stopped below the
    best so far, which never decreases: it cannot win later either), keyed by the pose's exact numbers
    (the lattice of poses meets the raster's cell edges, so a pose one unit in the last place away is
    scored anew)."""
    current = _score(pose, ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, score_inv, pair_d2, inv_line, -np.inf)
    seen_pose = np.empty((1 + 6 * max_iter, 3))
    seen_score = np.empty(1 + 6 * max_iter)
    seen_pose[0, 0], seen_pose[0, 1], seen_pose[0, 2] = pose[0], pose[1], pose[2]
    seen_score[0] = current
    seen = 1
    best = -1.0
    refinement = 0
    cand = np.empty(3)
    for _ in range(max_iter):
        if best >= current:
            refinement += 1
            step_xy *= 0.5
            step_phi *= 0.5
        best = current
        best_local = pose.copy()
        for move in range(6):
            cand[0], cand[1], cand[2] = pose[0], pose[1], pose[2]
            if move == 0:
                cand[0] += step_xy
            elif move == 1:
                cand[0] -= step_xy
            elif move == 2:
                cand[1] += step_xy
            elif move == 3:
                cand[1] -= step_xy
            elif move == 4:
                cand[2] += step_phi
            else:
                cand[2] -= step_phi
            e = _scored(cand, seen_pose, seen)
            if e >= 0:
                s = seen_score[e]
            else:
                s = _score(
                    cand, ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, score_inv, pair_d2, inv_line,
                    current,
                )  # fmt: skip
                seen_pose[seen, 0], seen_pose[seen, 1], seen_pose[seen, 2] = cand[0], cand[1], cand[2]
                seen_score[seen] = s
                seen += 1
            if s > current:
                current = s
                best_local[:] = cand
        pose[:] = best_local
        if not (current > best or refinement < levels):
            break
    return current


@njit(cache=True, inline="always")
def _solve3(normal, out):
    """out = -H^-1 g for the symmetric 3 x 3 H (its upper triangle) and g in `normal` (h00, h01, h02, h11,
    h12, h22, g0, g1, g2, as `_pass` fills it), by Cholesky; False when H is not positive definite (a scan
    that constrains no direction)."""
    h00, h01, h02, h11, h12, h22, g0, g1, g2 = (normal[0], normal[1], normal[2], normal[3], normal[4], normal[5],
                                                normal[6], normal[7], normal[8])  # fmt: skip
    if h00 <= 0.0:
        return False
    l00 = math.sqrt(h00)
    l10 = h01 / l00
    l20 = h02 / l00
    a11 = h11 - l10 * l10
    if a11 <= 0.0:
        return False
    l11 = math.sqrt(a11)
    l21 = (h12 - l20 * l10) / l11
    a22 = h22 - l20 * l20 - l21 * l21
    if a22 <= 0.0:
        return False
    l22 = math.sqrt(a22)
    y0 = -g0 / l00
    y1 = (-g1 - l10 * y0) / l11
    y2 = (-g2 - l20 * y0 - l21 * y1) / l22
    out[2] = y2 / l22
    out[1] = (y1 - l21 * out[2]) / l11
    out[0] = (y0 - l10 * out[1] - l20 * out[2]) / l00
    return True


@njit(cache=True)
def _pass(pose, ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, score_inv, pair_d2, inv_line, like_inv,
          miss_d2, normal):  # fmt: skip
    """One pass over the returns at `pose`: (score, log-likelihood, hits), and the Gauss-Newton normal
    equations of the score there in `normal` (h00, h01, h02, h11, h12, h22, g0, g1, g2).

    The score is `_score`'s sum, term for term in the same order. The log-likelihood is sum_j -min(d_j^2,
    miss_d2) like_inv, a return with no occupied cell near it counting miss_d2 (GMapping's
    `nullLikelihood`); hits counts the others. The normal equations are those of iteratively reweighted
    least squares on the score (its stationary points are those of sum_j omega_j d_j^2 with
    omega_j = w_j exp(-w_j d_j^2) held fixed, Welsch's M-estimator): each return's residual linearised in
    (x, y, phi), across the line through its two nearest cell means (d_j = n . (e_j - m), PL-ICP, Censi
    2008) or to the nearest mean (a 2-D residual). Each return's cells are searched once for all three."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    h00 = h01 = h02 = h11 = h12 = h22 = 0.0
    g0 = g1 = g2 = 0.0
    total = 0.0
    like = 0.0
    hits = 0
    for j in range(ends.shape[0]):
        lx, ly = ends[j, 0], ends[j, 1]
        ex = pose[0] + c * lx - s * ly  # as `_return_d2`, so that the score and the weight are its own
        ey = pose[1] + s * lx + c * ly
        ax = c * lx - s * ly  # the end point relative to the pose: d e / d phi = (-ay, ax)
        ay = s * lx + c * ly
        best, second, k1, k2 = _nearest_two(ex, ey, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy)
        if best < 0.0:
            like -= miss_d2 * like_inv
            continue
        hits += 1
        tx, ty, t2 = _surface_line(second, k1, k2, mean_xy, pair_d2)
        if t2 > 0.0:
            d2 = _across_d2(ex, ey, k1, tx, ty, t2, mean_xy)
            term = fast_exp(-d2 * inv_line)
            total += term
            inv_t = 1.0 / math.sqrt(t2)
            nxv, nyv = ty * inv_t, -tx * inv_t  # the line's unit normal
            d = (ex - mean_xy[k1, 0]) * nxv + (ey - mean_xy[k1, 1]) * nyv
            om = inv_line * term  # w exp(-w d^2), d^2 the squared distance across the line
            j2 = -ay * nxv + ax * nyv
            h00 += om * nxv * nxv
            h01 += om * nxv * nyv
            h02 += om * nxv * j2
            h11 += om * nyv * nyv
            h12 += om * nyv * j2
            h22 += om * j2 * j2
            g0 += om * nxv * d
            g1 += om * nyv * d
            g2 += om * j2 * d
        else:
            d2 = best
            term = fast_exp(-d2 * score_inv[j])
            total += term
            rx = ex - mean_xy[k1, 0]
            ry = ey - mean_xy[k1, 1]
            om = score_inv[j] * term
            h00 += om
            h02 -= om * ay
            h11 += om
            h12 += om * ax
            h22 += om * (ax * ax + ay * ay)
            g0 += om * rx
            g1 += om * ry
            g2 += om * (ax * ry - ay * rx)
        like -= min(d2, miss_d2) * like_inv
    normal[0], normal[1], normal[2], normal[3], normal[4], normal[5] = h00, h01, h02, h11, h12, h22
    normal[6], normal[7], normal[8] = g0, g1, g2
    return total, like, hits


@njit(cache=True)
def _finish(pose, ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, score_inv, pair_d2, inv_line, like_inv,
            miss_d2, iterations, tol_xy, tol_phi):  # fmt: skip
    """The score, log-likelihood and hits over all of `ends` at `pose`, after up to `iterations`
    Gauss-Newton steps on the score from it (`pose` moved in place): the normal equations of each pass
    (`_pass`) are solved and the step is kept if the score rises (else it is halved, up to twice). Stops
    when a step is below (tol_xy, tol_phi), no step raises the score, or after `iterations`. A continuous
    refinement where the climb's last step halvings probe a lattice of poses: the same optimum in a few
    passes over the returns instead of some fifty. Every pass scores, weighs and linearises at once, so
    a kept step's pass is the next step's linearisation and, at the end, the weight."""
    normal = np.empty(9)
    trial = np.empty(9)
    delta = np.empty(3)
    cand = np.empty(3)
    current, like, hits = _pass(pose, ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, score_inv, pair_d2,
                                inv_line, like_inv, miss_d2, normal)  # fmt: skip
    for _ in range(iterations):
        if not _solve3(normal, delta):
            break
        sc, sl, sh = -1.0, 0.0, 0
        for _halving in range(3):  # the step, then half and a quarter of it, until the score rises
            cand[:] = pose + delta
            sc, sl, sh = _pass(cand, ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, score_inv, pair_d2,
                               inv_line, like_inv, miss_d2, trial)  # fmt: skip
            if sc > current:
                break
            delta *= 0.5
        if sc <= current:
            break  # no step raises the score
        current, like, hits = sc, sl, sh
        pose[:] = cand
        normal[:] = trial
        if abs(delta[0]) < tol_xy and abs(delta[1]) < tol_xy and abs(delta[2]) < tol_phi:
            break
    return current, like, hits


@njit(cache=True)
def _fine_climb(pose, climb_ends, climb_inv,
                fine_ends, fine_inv, ends, score_inv, x0, y0, nx, ny, cell_m, kernel,
                grid, mean_xy, match):  # fmt: skip
    """The fine climb from `pose` (in place) on the returns `climb_ends` (every match_climb_stride-th of `ends`),
    with the steps and levels of `match`, its last match[13] step sizes on `fine_ends` (thinner still), then
    match[11] Gauss-Newton steps on all of `ends` (`_finish`, to within match[12] m and rad); returns the
    score, the log-likelihood and the hits over all of `ends`."""
    levels = int(match[2])
    fine = min(int(match[13]), levels)
    if fine > 0:
        # the larger steps on the climb's returns, down to the last `fine` step sizes; those on `fine_ends`
        _climb(pose, climb_ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, climb_inv, match[7],
               match[4], match[0], match[1], levels - fine, int(match[3]))  # fmt: skip
        f = 0.5 ** (levels - fine + 1)
        _climb(pose, fine_ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, fine_inv, match[7], match[4],
               match[0] * f, match[1] * f, fine - 1, int(match[3]))  # fmt: skip
    else:
        _climb(pose, climb_ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, climb_inv, match[7],
               match[4], match[0], match[1], levels, int(match[3]))  # fmt: skip
    return _finish(pose, ends, x0, y0, nx, ny, cell_m, kernel, grid, mean_xy, score_inv, match[7], match[4],
                   match[5], match[6], int(match[11]), match[12], match[12])  # fmt: skip


@njit(cache=True, inline="always")
def _weigh(i, pose, result, out):
    """Particle i's result: the matched pose, and its (score, log-likelihood, hits) there."""
    out[i, 0], out[i, 1], out[i, 2] = pose[0], pose[1], pose[2]
    out[i, 3], out[i, 4], out[i, 5] = result[0], result[1], result[2]


@njit(cache=True)
def _match_one(i, map_xy, map_p, lo, hi, pose0, climb_ends, climb_inv,
               fine_ends, fine_inv, ends, score_inv, window,
               cell_m, kernel, min_p, match, grid, sums, touched, out):  # fmt: skip
    """Rasterise particle i's window of its map, climb the score from the motion sample, weigh the scan
    there; reset the raster."""
    x0, y0 = window[0], window[1]
    nx, ny = int(window[2]), int(window[3])
    pose = pose0.copy()
    used = _rasterise(map_xy, map_p, lo, hi, min_p, x0, y0, nx, ny, cell_m, grid, sums, touched)
    if used:
        result = _fine_climb(pose, climb_ends, climb_inv,
                             fine_ends, fine_inv, ends, score_inv, x0, y0, nx, ny, cell_m,
                             kernel, grid, sums, match)  # fmt: skip
    else:  # no map here: every return misses
        result = _finish(pose, ends, x0, y0, nx, ny, cell_m, kernel, grid, sums, score_inv, match[7], match[4],
                         match[5], match[6], 0, match[12], match[12])  # fmt: skip
    _weigh(i, pose, result, out)
    for slot in range(used):
        grid[touched[slot]] = _EMPTY


@njit(cache=True)
def _coarse_start_one(i, map_xy, map_p, lo, hi, pose0, climb_ends, climb_inv,
                      fine_ends, fine_inv, ends, score_inv,
                      coarse_ends, coarse_inv, window, cell_m, kernel, min_p, match, grid, sums, touched,
                      coarse_grid, coarse_sums, coarse_touched, out):  # fmt: skip
    """The second start, coarse to fine, for particle i whose fine match is in out[i]: climb from the
    motion sample down a pyramid of rasters, each match[8] times coarser than the one below
    (coarse_sums.shape[0] levels; on each, every width, reach and step scaled by its factor, so a
    return finds the map up to that many times further away), from the coarsest to the one just above
    the fine raster. Where that ends within a cell of the lowest level and factor / 2 angular steps of the
    fine match, the pyramid cannot tell the two apart and the fine match stands; else the fine raster is
    climbed from there too, and its result replaces the fine match when it scores higher by at least
    match[10] x the returns (a jump against the odometry must be paid for by returns it explains).
    Resets every raster."""
    x0, y0 = window[0], window[1]
    nx, ny = int(window[2]), int(window[3])
    factor = int(match[8])
    depth = coarse_sums.shape[0]
    cused = np.zeros(depth, dtype=np.int64)
    base = np.zeros(depth, dtype=np.int64)
    used = _rasterise_pyramid(
        map_xy, map_p, lo, hi, min_p, x0, y0, nx, ny, cell_m, grid, sums, touched,
        factor, coarse_grid, coarse_sums, coarse_touched, cused, base,
    )  # fmt: skip
    if used and cused[0]:
        second = pose0.copy()
        for lv in range(depth - 1, -1, -1):
            fl, cnx, cny = _level_shape(nx, ny, factor, lv)
            f2 = float(fl * fl)
            _climb(
                second,
                coarse_ends,
                x0,
                y0,
                cnx,
                cny,
                cell_m * fl,
                kernel,
                coarse_grid[base[lv] : base[lv] + cnx * cny],
                coarse_sums[lv],
                coarse_inv / f2,
                match[7] * f2,
                match[4] / f2,
                match[0] * fl,
                match[1] * fl,
                int(match[9]),
                int(match[3]),
            )
        cc = cell_m * factor
        dx, dy = second[0] - out[i, 0], second[1] - out[i, 1]
        if dx * dx + dy * dy > cc * cc or abs(second[2] - out[i, 2]) > 0.5 * factor * match[1]:
            result = _fine_climb(second, climb_ends, climb_inv,
                                 fine_ends, fine_inv, ends, score_inv, x0, y0, nx, ny,
                                 cell_m, kernel, grid, sums, match)  # fmt: skip
            if result[0] > out[i, 3] + match[10] * ends.shape[0]:
                _weigh(i, second, result, out)
    for slot in range(used):
        grid[touched[slot]] = _EMPTY
    for lv in range(depth):
        for slot in range(cused[lv]):
            coarse_grid[coarse_touched[lv, slot]] = _EMPTY


@njit(cache=True, parallel=True, nogil=True)
def _match_all(map_xy, map_p, lo, hi, poses, climb_ends, climb_inv,
               fine_ends, fine_inv, ends, score_inv, windows,
               cell_m, kernel, min_p, match, grids, sums, touched):  # fmt: skip
    """_match_one for every particle, spread over the workers (one raster each)."""
    n = poses.shape[0]
    out = np.empty((n, 6))
    counter = np.zeros(1, dtype=np.int64)
    for w in prange(grids.shape[0]):
        while True:
            i = next_index(counter)  # the next particle not taken (gslam.workqueue)
            if i >= n:
                break
            _match_one(i, map_xy, map_p, lo[i], hi[i], poses[i], climb_ends, climb_inv,
                       fine_ends, fine_inv, ends,
                       score_inv, windows[i], cell_m, kernel, min_p, match, grids[w], sums[w], touched[w],
                       out)  # fmt: skip
    return out


@njit(cache=True, parallel=True, nogil=True)
def _coarse_start_all(chosen, map_xy, map_p, lo, hi, poses, climb_ends, climb_inv,
                      fine_ends, fine_inv, ends,
                      score_inv, coarse_ends, coarse_inv, windows, cell_m, kernel, min_p, match, grids,
                      sums, touched, coarse_grids, coarse_sums, coarse_touched, out):  # fmt: skip
    """_coarse_start_one for the particles `chosen`, spread over the workers; updates `out` in place."""
    counter = np.zeros(1, dtype=np.int64)
    for w in prange(grids.shape[0]):
        while True:
            k = next_index(counter)
            if k >= chosen.shape[0]:
                break
            i = chosen[k]
            _coarse_start_one(i, map_xy, map_p, lo[i], hi[i], poses[i], climb_ends, climb_inv,
                              fine_ends, fine_inv, ends,
                              score_inv, coarse_ends, coarse_inv, windows[i], cell_m, kernel, min_p, match,
                              grids[w], sums[w], touched[w], coarse_grids[w], coarse_sums[w], coarse_touched[w],
                              out)  # fmt: skip


@dataclass(frozen=True)
class MatchSettings:
    """The settings `match_and_weigh` takes (its keyword names) but the coarse start's: the update's from
    FilterConfig's match_* options (`from_config`), the placement's with its own steps."""

    cell_m: float
    kernel: int
    min_p: float
    margin_m: float
    step_xy_m: float
    step_phi_rad: float
    levels: int
    max_iterations: int
    score_sigma_m: float
    score_sigma_rad: float | None
    """None: the scan's own angle between beams (`arguments`)."""
    like_sigma_m: float
    miss_m: float
    line_pair_m: float
    polish_iterations: int
    climb_stride: int
    fine_stride: int
    fine_levels: int

    @classmethod
    def from_config(cls, cfg: FilterConfig) -> MatchSettings:
        return cls(
            cell_m=cfg.match_cell_m,
            kernel=cfg.match_kernel,
            min_p=cfg.match_min_p,
            margin_m=cfg.match_window_margin_m,
            step_xy_m=cfg.match_step_xy_m,
            step_phi_rad=cfg.match_step_phi_rad,
            levels=cfg.match_levels,
            max_iterations=cfg.match_max_iterations,
            score_sigma_m=cfg.match_sigma_m,
            score_sigma_rad=cfg.match_sigma_rad,
            like_sigma_m=cfg.weight_sigma_m,
            miss_m=cfg.weight_miss_m,
            line_pair_m=cfg.match_line_pair_m,
            polish_iterations=cfg.match_polish_iterations,
            climb_stride=cfg.match_climb_stride,
            fine_stride=cfg.match_fine_stride,
            fine_levels=cfg.match_fine_levels,
        )

    def parameters(self) -> np.ndarray:
        """The kernels' `match` array for these settings, as `match_and_weigh` builds it without a coarse
        start."""
        return match_parameters(
            self.step_xy_m, self.step_phi_rad, self.levels, self.max_iterations, self.score_sigma_m,
            self.like_sigma_m, self.miss_m, self.line_pair_m, 1, 2, 0.0, self.polish_iterations, POLISH_TOLERANCE,
            self.fine_levels if self.fine_stride > 1 else 0,
        )  # fmt: skip

    def arguments(self, angle_increment_rad: float) -> dict[str, Any]:
        """`match_and_weigh`'s keyword arguments for a scan whose beams are `angle_increment_rad` apart."""
        args = asdict(self)
        if self.score_sigma_rad is None:
            args["score_sigma_rad"] = angle_increment_rad
        return args


class MatchWorkspace:
    """Rasters reused between calls (per worker: one fine raster and the coarse pyramid above it, whose
    levels share one cell array), grown when a larger window or map comes."""

    def __init__(self, workers: int) -> None:
        self.workers = max(1, int(workers))
        self.grids = np.full((self.workers, 0), _EMPTY, dtype=np.int32)
        self.sums = np.empty((self.workers, 0, 3))
        self.touched = np.empty((self.workers, 0), dtype=np.int64)
        self.coarse_grids = np.full((self.workers, 0), _EMPTY, dtype=np.int32)
        self.coarse_sums = np.empty((self.workers, 0, 0, 3))
        self.coarse_touched = np.empty((self.workers, 0, 0), dtype=np.int64)

    def reserve(self, cells: int, points: int, coarse_cells: int = 0, depth: int = 0) -> None:
        if cells > self.grids.shape[1]:
            self.grids = np.full((self.workers, int(cells * 1.25) + 1), _EMPTY, dtype=np.int32)
        if coarse_cells > self.coarse_grids.shape[1]:
            self.coarse_grids = np.full((self.workers, int(coarse_cells * 1.25) + 1), _EMPTY, dtype=np.int32)
        if points > self.sums.shape[1]:
            size = int(points * 1.5) + 1
            self.sums = np.empty((self.workers, size, 3))
            self.touched = np.empty((self.workers, size), dtype=np.int64)
        if depth and (points > self.coarse_sums.shape[2] or depth != self.coarse_sums.shape[1]):
            size = max(int(points * 1.5) + 1, self.coarse_sums.shape[2])
            self.coarse_sums = np.empty((self.workers, depth, size, 3))
            self.coarse_touched = np.empty((self.workers, depth, size), dtype=np.int64)


def _every(stride: int, arrays: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """Every `stride`-th row of each of `arrays` (the returns a climb scores), contiguous for the compiled
    loops; the arrays themselves for a stride of 1."""
    k = max(1, int(stride))
    return arrays if k == 1 else tuple(np.ascontiguousarray(a[::k]) for a in arrays)


def match_parameters(
    step_xy_m: float,
    step_phi_rad: float,
    levels: int,
    max_iterations: int,
    score_sigma_m: float,
    like_sigma_m: float,
    miss_m: float,
    line_pair_m: float,
    coarse_factor: int,
    coarse_levels: int,
    coarse_min_gain: float,
    polish_iterations: int,
    polish_tolerance: float,
    fine_levels: int,
) -> np.ndarray:
    """The compiled kernels' `match` array: the settings as they read them (`_fine_climb`, `_coarse_start_one`),
    with the score's and the weight's widths as 0.5 / sigma^2 and the distances squared."""
    return np.array(
        [
            step_xy_m,
            step_phi_rad,
            levels,
            max_iterations,
            0.5 / score_sigma_m**2,
            0.5 / like_sigma_m**2,
            miss_m**2,
            line_pair_m**2,
            coarse_factor,
            coarse_levels,
            coarse_min_gain,
            polish_iterations,
            polish_tolerance,
            fine_levels,
        ]
    )


def match_and_weigh(
    map_xy: np.ndarray,
    map_p: np.ndarray,
    map_lo: np.ndarray,
    map_hi: np.ndarray,
    poses: np.ndarray,
    ends_sensor: np.ndarray,
    *,
    cell_m: float,
    kernel: int,
    min_p: float,
    margin_m: float,
    step_xy_m: float,
    step_phi_rad: float,
    levels: int,
    max_iterations: int,
    score_sigma_m: float,
    score_sigma_rad: float,
    like_sigma_m: float,
    miss_m: float,
    line_pair_m: float,
    workspace: MatchWorkspace,
    coarse_factor: int = 1,
    coarse_levels: int = 2,
    coarse_stride: int = 1,
    coarse_min_gain: float = 0.0,
    coarse_depth: int = 1,
    coarse_gate: float = math.inf,
    coarse_reference: float = 0.0,
    polish_iterations: int = 0,
    polish_tolerance: float = POLISH_TOLERANCE,
    climb_stride: int = 1,
    fine_stride: int = 1,
    fine_levels: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Match the scan end points `ends_sensor` (K, 2) against each particle's map and weigh it there.

    Particle i's map is map_xy[map_lo[i]:map_hi[i]] with probabilities map_p[...]; `line_pair_m` 0 scores
    every return point to point. `coarse_factor` > 1: a second start, climbed from the motion sample on a
    raster that many times coarser (cells, widths, steps, line pairs all scaled; `coarse_depth` levels,
    each `coarse_factor` times coarser than the one below, climbed from the coarsest down), `coarse_levels`
    step halvings on each, on every `coarse_stride`-th of the climb's returns; where it ends more than a
    coarse cell (or factor / 2 angular steps) from the fine climb's result it is climbed on the fine
    raster too, and replaces that
    result when it scores `coarse_min_gain` x the returns higher. The second start is tried only for the
    particles whose fine fit (score / returns) is at most `coarse_gate` x the reference fit: the best fine
    fit among the particles, or `coarse_reference` if higher (the filter passes the median fit of its
    previous update, so a slip that takes every particle out of the fine climb's basin is still caught);
    above 1: every particle. `climb_stride` k > 1: the climbs score every k-th return, and their last
    `fine_levels` step sizes every `fine_stride`-th of those; the Gauss-Newton finish (`polish_iterations`),
    the scores returned and the weight use all. Returns (matched
    poses (N, 3), score at the matched pose (N,), log-likelihood there (N,), returns that found an
    occupied cell near their end point (N,)).
    """
    n = len(poses)
    poses = np.ascontiguousarray(poses, dtype=float)
    ends = np.ascontiguousarray(ends_sensor, dtype=float)
    rng = np.hypot(ends[:, 0], ends[:, 1])
    if len(ends) == 0:
        return poses.copy(), np.zeros(n), np.zeros(n), np.zeros(n, dtype=np.int64)
    x0, y0, x1, y1 = window_boxes(poses, ends, margin_m)
    nx = np.ceil((x1 - x0) / cell_m) + 1
    ny = np.ceil((y1 - y0) / cell_m) + 1
    windows = np.column_stack([x0, y0, nx, ny])
    sizes = (map_hi - map_lo) if n else np.zeros(0, dtype=np.int64)
    f = max(1, int(coarse_factor))
    depth = max(1, int(coarse_depth)) if f > 1 else 0
    coarse_cells = sum(int(((nx // f ** (lv + 1) + 1) * (ny // f ** (lv + 1) + 1)).max()) for lv in range(depth))
    workspace.reserve(int((nx * ny).max()), int(sizes.max()) if n else 0, coarse_cells, depth)
    match = match_parameters(
        step_xy_m, step_phi_rad, levels, max_iterations, score_sigma_m, like_sigma_m, miss_m, line_pair_m, f,
        coarse_levels, coarse_min_gain, polish_iterations, polish_tolerance, fine_levels if fine_stride > 1 else 0,
    )  # fmt: skip
    score_inv = 0.5 / (score_sigma_m**2 + (rng * score_sigma_rad) ** 2)
    map_xy = np.ascontiguousarray(map_xy, dtype=MAP_DTYPE)
    map_p = np.ascontiguousarray(map_p, dtype=MAP_DTYPE)
    lo = np.asarray(map_lo, dtype=np.int64)
    hi = np.asarray(map_hi, dtype=np.int64)
    grids = (workspace.grids, workspace.sums, workspace.touched)
    thinned = _every(climb_stride, (ends, score_inv))
    climb = (*thinned, *_every(fine_stride, thinned))
    out = _match_all(map_xy, map_p, lo, hi, poses, *climb, ends, score_inv, windows, float(cell_m), int(kernel),
                     float(min_p), match, *grids)  # fmt: skip
    if f > 1 and max_iterations > 0:
        fit = out[:, 3] / len(ends)
        reference = max(float(fit.max()), float(coarse_reference))
        chosen = np.flatnonzero(fit <= coarse_gate * reference).astype(np.int64)
        if len(chosen):
            _coarse_start_all(
                chosen, map_xy, map_p, lo, hi, poses, *climb, ends, score_inv,
                *_every(coarse_stride, thinned), windows, float(cell_m), int(kernel), float(min_p),
                match, *grids, workspace.coarse_grids, workspace.coarse_sums, workspace.coarse_touched, out,
            )  # fmt: skip
    return out[:, :3].copy(), out[:, 3].copy(), out[:, 4].copy(), out[:, 5].astype(np.int64)
