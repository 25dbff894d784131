"""Steps 2 to 4 of the algorithm with numpy over whole maps, for every reading of the open points.

All particles' points are concatenated with an `owner` index (`FlatMaps`), so projection, q (eq. 6),
the update of eq. 7, generation, pruning and density control are vectorised over particles, points
and beams. The filter runs this path for any setting `gslam.mapupdate.windowed` does not support
(`gslam.mapupdate.select`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gslam.config import FilterConfig
from gslam.pointmap import FlatMaps, PointMap, owner_cell_keys, segment_sum
from gslam.scan import Scan, inverse_measure, measure
from gslam.weights import log_weight_beam_sum, log_weight_likelihood_field, log_weight_sum

_RANK_BITS = 11

OPTIONS = (
    "particles",
    "points_per_observation",
    "observation_unit",
    "range_sigma_m",
    "bearing_sigma_rad",
    "hit_sigma_m",
    "hit_ratio",
    "free_ratio",
    "free_space_beams",
    "no_return_free_m",
    "map_update",
    "prune_threshold",
    "prune_relative",
    "max_points_per_cell",
    "cell_size_m",
    "weighting",
    "weight_sigma_m",
    "weight_floor",
    "weight_tempering",
    "weight_beam_stride",
    "weight_gain",
    "prior_interpolation",
    "prior_neighbours",
    "prior_radius_m",
    "prior_p0",
)
"""Every setting this implementation reads (some only in some readings: prior_neighbours with the
nearest-mean and IDW priors, the weight's settings with the weights computed here)."""


def supports(cfg: FilterConfig) -> bool:
    """Every reading of the open points: this is the reference implementation."""
    return True


def options(cfg: FilterConfig) -> dict[str, Any]:
    """The settings of cfg this implementation reads (`OPTIONS`)."""
    return {k: getattr(cfg, k) for k in OPTIONS}


def point_likelihood_ratio(
    range_m: np.ndarray,
    measured_m: np.ndarray,
    observed: np.ndarray,
    cfg: FilterConfig,
    free_up_to_m: np.ndarray | None = None,
) -> np.ndarray:
    """q_k (eq. 6) relative to an unobserved point, for points at `range_m` on beams that measured `measured_m`.

    Near the return: up to hit_ratio (Gaussian in range, width hit_sigma_m). In front of it (observed free
    space): free_ratio. Behind it (occluded), outside the field of view or beyond the maximum range: 1.
    `free_up_to_m` (default: `measured_m`) limits the free space: a point in front of its own beam's
    return but not in front of `free_up_to_m` (the neighbouring beams' returns) is left as if occluded.
    """
    d = range_m - measured_m
    g = np.exp(-0.5 * np.square(d / cfg.hit_sigma_m))
    q = cfg.free_ratio + (cfg.hit_ratio - cfg.free_ratio) * g
    occluded = d > 0
    if free_up_to_m is not None:
        occluded |= range_m >= free_up_to_m
    q = np.where(occluded, 1.0 + (cfg.hit_ratio - 1.0) * g, q)
    return np.where(observed, q, 1.0)


def project(
    flat: FlatMaps, poses: np.ndarray, scan: Scan, free_space_beams: int = 0, no_return_free_m: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Project every point into its owner's scan: (range, beam index, measured range on it, observed mask,
    free-space limit).

    A point is observed when it falls inside the field of view and closer than the maximum range. Beams
    without a return measured free space up to the maximum range, or `no_return_free_m` (nearer: points
    beyond it on such a beam are not observed). The free-space limit is the shortest
    range measured by the point's beam and `free_space_beams` beams either side of it.
    """
    geom = scan.geometry
    r, b = measure(poses[flat.owner], flat.xy)
    j = np.rint((b - geom.start_angle_rad) / geom.angle_increment_rad).astype(np.int64)
    in_fov = (j >= 0) & (j < geom.beam_count)
    j = np.clip(j, 0, geom.beam_count - 1)
    ranges = scan.occlusion_ranges_m
    z = ranges[j]
    free = z
    if free_space_beams > 0:
        k = free_space_beams
        padded = np.concatenate([np.full(k, np.inf), ranges, np.full(k, np.inf)])
        window = np.lib.stride_tricks.sliding_window_view(padded, 2 * k + 1).min(axis=1)
        free = window[j]
    observed = in_fov & (r < geom.max_range_m)
    if no_return_free_m is not None:
        observed &= (z < geom.max_range_m) | (r < no_return_free_m)
    return r, j, z, observed, free


def interpolate_prior(maps: list[PointMap], owner: np.ndarray, xy: np.ndarray, cfg: FilterConfig) -> np.ndarray:
    """p_hat_{t-1} of new points from their particle's existing points (open point 5).

    Where no existing point lies within prior_radius_m: prior_p0 (a probability for the binary map,
    else a multiple of the particle's mean p).
    """
    if cfg.prior_interpolation == "cell_mean":
        return _cell_mean_prior(maps, owner, xy, cfg)
    prior = np.empty(len(xy))
    for i, m in enumerate(maps):  # per particle: one vectorised KD-tree query each
        sel = owner == i
        if not sel.any():
            continue
        default = cfg.prior_p0 if cfg.map_update == "binary" else cfg.prior_p0 * m.mean_p
        if cfg.prior_interpolation == "constant" or len(m) == 0:
            prior[sel] = default
            continue
        k = min(cfg.prior_neighbours, len(m))
        dist, idx = m.tree.query(xy[sel], k=k, distance_upper_bound=cfg.prior_radius_m)
        dist = dist.reshape(len(dist), -1)
        idx = idx.reshape(len(idx), -1)
        found = np.isfinite(dist)
        pk = np.where(found, m.p[np.minimum(idx, len(m) - 1)], 0.0)
        if cfg.prior_interpolation == "idw":
            wk = np.where(found, 1.0 / np.maximum(dist, 1e-3), 0.0)
        else:
            wk = found.astype(float)
        wsum = wk.sum(axis=1)
        prior[sel] = np.where(wsum > 0, (wk * pk).sum(axis=1) / np.maximum(wsum, 1e-300), default)
    return prior


def _prior_default(maps: list[PointMap], cfg: FilterConfig) -> np.ndarray:
    if cfg.map_update == "binary":
        return np.full(len(maps), cfg.prior_p0)
    return cfg.prior_p0 * np.array([m.mean_p for m in maps])


def _cell_mean_prior(maps: list[PointMap], owner: np.ndarray, xy: np.ndarray, cfg: FilterConfig) -> np.ndarray:
    """Mean p of the particle's points in the new point's grid cell (maps are sorted by cell, so this is
    two binary searches over all particles at once); prior_p0 where the cell is empty."""
    flat = FlatMaps.of(maps)
    default = _prior_default(maps, cfg)[owner]
    if len(flat.p) == 0:
        return default
    keys = owner_cell_keys(flat.owner, flat.xy, cfg.cell_size_m)
    query = owner_cell_keys(owner, xy, cfg.cell_size_m)
    lo = np.searchsorted(keys, query, side="left")
    hi = np.searchsorted(keys, query, side="right")
    csum = np.concatenate([[0.0], np.cumsum(flat.p)])
    count = hi - lo
    return np.where(count > 0, (csum[hi] - csum[lo]) / np.maximum(count, 1), default)


def draw_new_points(
    poses: np.ndarray, scan: Scan, cfg: FilterConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Draw z_hat ~ N(z, R) around the returns and map them through the inverse of g (step 2).

    Returns (owner, xy, q_hat relative to unobserved, return index) for all particles.
    """
    _, z, b = scan.return_polar()
    n = len(poses)
    if len(z) == 0:
        return np.empty(0, dtype=np.int64), np.empty((0, 2)), np.empty(0), np.empty(0, dtype=np.int64)
    m = cfg.points_per_observation
    if cfg.observation_unit == "beam":
        ret = np.tile(np.repeat(np.arange(len(z)), m), n)
        owner = np.repeat(np.arange(n), len(z) * m)
    else:
        ret = rng.integers(0, len(z), size=n * m)
        owner = np.repeat(np.arange(n), m)
    dr = rng.standard_normal(len(ret)) * cfg.range_sigma_m
    db = rng.standard_normal(len(ret)) * cfg.bearing_sigma_rad
    z_hat = z[ret] + dr
    xy = inverse_measure(poses[owner], z_hat, b[ret] + db)
    observed = np.ones(len(ret), dtype=bool)
    q_hat = point_likelihood_ratio(z_hat, z[ret], observed, cfg)
    return owner, xy, q_hat, ret


def update_probabilities(
    p_prev: np.ndarray, q: np.ndarray, owner: np.ndarray, observed: np.ndarray, n: int, cfg: FilterConfig
) -> np.ndarray:
    """The recursive update of eq. 7 (step 3), in the semantic cfg.map_update selects (open point 3).

    global:   p_t^k = q_k p_{t-1}^k / sum_j q_j p_{t-1}^j over all the particle's points (literal eq. 7).
    observed: the same sum over the points this scan observes, rescaled to keep their total mass, so
              points out of view keep their p.
    binary:   each p_k is the probability that theta_k is an obstacle: logit p += log q_k.
    """
    if cfg.map_update == "binary":
        logit = np.log(p_prev) - np.log1p(-p_prev) + np.log(q)
        return np.clip(1.0 / (1.0 + np.exp(-logit)), 1e-6, 1 - 1e-6)
    qp = q * p_prev
    if cfg.map_update == "global":
        return qp / segment_sum(qp, owner, n)[owner]
    obs = observed.astype(float)
    mass_before = segment_sum(p_prev * obs, owner, n)
    mass_after = segment_sum(qp * obs, owner, n)
    scale = np.where(mass_after > 0, mass_before / np.maximum(mass_after, 1e-300), 1.0)
    return np.where(observed, qp * scale[owner], p_prev)


def prune_and_thin(flat: FlatMaps, n: int, cfg: FilterConfig) -> FlatMaps:
    """Step 4: drop points with p < p_thr (optionally relative to the mean), then keep at most
    max_points_per_cell points (the most probable) per cell, per particle."""
    if cfg.prune_relative:
        counts = np.bincount(flat.owner, minlength=n)
        mean_p = segment_sum(flat.p, flat.owner, n) / np.maximum(counts, 1)
        keep = flat.p >= cfg.prune_threshold * mean_p[flat.owner]
    else:
        keep = flat.p >= cfg.prune_threshold
    xy, p, owner = flat.xy[keep], flat.p[keep], flat.owner[keep]
    if len(p) == 0:
        return FlatMaps(xy, p, owner)
    key = owner_cell_keys(owner, xy, cfg.cell_size_m)
    # One int64 sort by (particle, cell, descending p): p ranked on 11 bits inside each cell.
    scale = p.max() if cfg.map_update != "binary" else 1.0
    rank = np.floor((1.0 - np.clip(p / scale, 0.0, 1.0)) * ((1 << _RANK_BITS) - 1)).astype(np.int64)
    order = np.argsort((key << _RANK_BITS) | rank)
    if cfg.max_points_per_cell > 0:
        ks = key[order]
        start = np.r_[0, np.flatnonzero(np.diff(ks)) + 1]
        within = np.arange(len(ks)) - np.repeat(start, np.diff(np.r_[start, len(ks)]))
        order = order[within < cfg.max_points_per_cell]
    xy, p, owner = xy[order], p[order], owner[order]
    return FlatMaps(xy, p, owner)


class WholeMapUpdate:
    """Steps 2 to 5 with numpy over whole maps, for every reading of the open points."""

    def __init__(self, cfg: FilterConfig) -> None:
        self.cfg = cfg

    def __call__(
        self,
        maps: list[PointMap],
        layout: tuple[np.ndarray, ...] | None,
        poses: np.ndarray,
        scan: Scan,
        rng: np.random.Generator,
        matched_log_like: np.ndarray,
    ) -> tuple[list[PointMap], None, np.ndarray, int]:
        """(new maps, None (no shared layout), the step's log-likelihoods, points in all maps)."""
        cfg = self.cfg
        n = cfg.particles
        flat = FlatMaps.of(maps)
        # 2. Generate new points around the returns (drawn z_hat, inverse of g, interpolated prior).
        new_owner, new_xy, new_q, _ = draw_new_points(poses, scan, cfg, rng)
        new_prior = interpolate_prior(maps, new_owner, new_xy, cfg) if len(new_owner) else np.empty(0)
        # 3. q of existing points (eq. 6) and the update of eq. 7 over existing and new points.
        r, j, z, observed, free = project(flat, poses, scan, cfg.free_space_beams, cfg.no_return_free_m)
        q = point_likelihood_ratio(r, z, observed, cfg, free)
        all_q = np.concatenate([q, new_q])
        all_prev = np.concatenate([flat.p, new_prior])
        all_owner = np.concatenate([flat.owner, new_owner])
        all_observed = np.concatenate([observed, np.ones(len(new_q), dtype=bool)])
        order = np.argsort(all_owner, kind="stable")
        all_xy = np.concatenate([flat.xy, new_xy])[order]
        all_q, all_prev, all_owner, all_observed = all_q[order], all_prev[order], all_owner[order], all_observed[order]
        # 5. Importance factors (computed from q and p_{t-1}, before the map changes).
        if cfg.weighting == "sum":
            log_like = log_weight_sum(all_q, all_prev, all_owner, n)
        elif cfg.weighting == "beam_sum":
            log_like = log_weight_beam_sum(flat, r, j, z, observed, scan, n, cfg)
        elif cfg.weighting == "likelihood_field":
            log_like = log_weight_likelihood_field(maps, poses, scan, cfg)
        else:
            log_like = matched_log_like / (cfg.weight_gain * n)
        if flat.p.size == 0:
            log_like = np.zeros(n)  # first scan: nothing to compare with
        p_new = update_probabilities(all_prev, all_q, all_owner, all_observed, n, cfg)
        # 4. Remove meaningless points (and thin dense cells).
        pruned = prune_and_thin(FlatMaps(all_xy, p_new, all_owner), n, cfg)
        return pruned.split(n), None, log_like, len(pruned.p)
