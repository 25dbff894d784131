"""Scan against the likelihood field, compiled and parallel over the particles: the climb of the scan-matching
proposal and the observation likelihood.

The score of a pose is sum_j exp(-d_j^2 / 2 sigma^2), d_j the field's distance at return j's end point:
the number of returns the map explains, as the SLAM matcher scores (`gslam.scanmatch`). The climb is
GMapping's (`ScanMatcher::optimize`): one step forwards and backwards in x, y and heading, move to the best
while it improves, halve the steps when it does not, `levels` times.

The likelihood of the scan is the product over returns of z_hit exp(-d_j^2 / 2 sigma^2) + z_rand (the
likelihood-field model with a uniform part for what the map does not hold: people, doors, clutter).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from gslam.localise.field import LikelihoodField, value_at


@njit(cache=True)
def _score(x, y, phi, ends, x0, y0, cell_m, grid, beat):  # pragma: no cover - compiled
    """Sum of the score grid (values in [0, 1]) at the end points; -1 as soon as it cannot reach `beat`."""
    c, s = math.cos(phi), math.sin(phi)
    total = 0.0
    count = ends.shape[0]
    bound = beat - 1e-9
    for j in range(count):
        if total + (count - j) < bound:
            return -1.0
        ex = x + c * ends[j, 0] - s * ends[j, 1]
        ey = y + s * ends[j, 0] + c * ends[j, 1]
        total += value_at(ex, ey, x0, y0, cell_m, grid, 0.0)
    return total


@njit(cache=True, parallel=True)
def _climb_all(poses, ends, x0, y0, cell_m, grid, step_xy, step_phi, levels, max_iter):  # pragma: no cover
    n = poses.shape[0]
    scores = np.empty(n)
    for i in prange(n):
        x, y, phi = poses[i, 0], poses[i, 1], poses[i, 2]
        current = _score(x, y, phi, ends, x0, y0, cell_m, grid, -np.inf)
        sxy, sphi = step_xy, step_phi
        refinement = 0
        for _ in range(max_iter):
            best = current
            bx, by, bphi = x, y, phi
            for move in range(6):
                cx, cy, cphi = x, y, phi
                if move == 0:
                    cx += sxy
                elif move == 1:
                    cx -= sxy
                elif move == 2:
                    cy += sxy
                elif move == 3:
                    cy -= sxy
                elif move == 4:
                    cphi += sphi
                else:
                    cphi -= sphi
                sc = _score(cx, cy, cphi, ends, x0, y0, cell_m, grid, best)
                if sc > best:
                    best, bx, by, bphi = sc, cx, cy, cphi
            if best > current:
                current, x, y, phi = best, bx, by, bphi
            else:
                refinement += 1
                if refinement > levels:
                    break
                sxy *= 0.5
                sphi *= 0.5
        poses[i, 0], poses[i, 1] = x, y
        poses[i, 2] = (phi + math.pi) % (2.0 * math.pi) - math.pi
        scores[i] = current
    return scores


@njit(cache=True, parallel=True)
def _sums_all(poses, ends, x0, y0, cell_m, log_grid, log_outside, fit_grid):  # pragma: no cover
    n = poses.shape[0]
    out = np.empty(n)
    fit = np.empty(n)
    for i in prange(n):
        c, s = math.cos(poses[i, 2]), math.sin(poses[i, 2])
        total = 0.0
        explained = 0.0
        for j in range(ends.shape[0]):
            ex = poses[i, 0] + c * ends[j, 0] - s * ends[j, 1]
            ey = poses[i, 1] + s * ends[j, 0] + c * ends[j, 1]
            total += value_at(ex, ey, x0, y0, cell_m, log_grid, log_outside)
            explained += value_at(ex, ey, x0, y0, cell_m, fit_grid, 0.0)
        out[i] = total
        fit[i] = explained / max(1, ends.shape[0])
    return out, fit


class ScanModel:
    """The field's distances turned, once, into the grids the kernels read: the climb's score
    exp(-d^2 / 2 sigma_match^2), the weight's log(z_hit exp(-d^2 / 2 sigma^2) + z_rand) and the fitness
    exp(-d^2 / 2 sigma^2) (precomputed likelihoods, as AMCL's map_update_cspace; a lookup per return)."""

    def __init__(self, field: LikelihoodField, match_sigma_m: float, sigma_m: float, z_hit: float, z_rand: float):
        d2 = field.distance_m**2
        self.field = field
        self.score = np.exp(-d2 / (2 * match_sigma_m**2))
        self.fit = np.exp(-d2 / (2 * sigma_m**2))
        self.log_like = np.log(z_hit * self.fit + z_rand)
        self.log_outside = math.log(z_hit * math.exp(-(field.max_distance_m**2) / (2 * sigma_m**2)) + z_rand)


def climb(
    model: ScanModel,
    poses: np.ndarray,
    ends: np.ndarray,
    step_xy_m: float,
    step_phi_rad: float,
    levels: int,
    max_iterations: int = 60,
) -> np.ndarray:
    """Hill-climb every pose (N, 3) in place on the score of the scan end points `ends` (K, 2, sensor
    frame); returns the scores (N,)."""
    if len(poses) == 0 or len(ends) == 0:
        return np.zeros(len(poses))
    f = model.field
    return _climb_all(poses, np.ascontiguousarray(ends, dtype=float), f.origin_xy_m[0], f.origin_xy_m[1], f.cell_m,
                      model.score, step_xy_m, step_phi_rad, int(levels), int(max_iterations))  # fmt: skip


def log_likelihood(model: ScanModel, poses: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(log-likelihood of the scan at each pose (N,), fitness: the mean of exp(-d^2 / 2 sigma^2) over the
    returns, the share of the scan the map explains (N,))."""
    if len(ends) == 0:
        return np.zeros(len(poses)), np.zeros(len(poses))
    f = model.field
    return _sums_all(np.ascontiguousarray(poses, dtype=float), np.ascontiguousarray(ends, dtype=float),
                     f.origin_xy_m[0], f.origin_xy_m[1], f.cell_m, model.log_like, model.log_outside,
                     model.fit)  # fmt: skip
