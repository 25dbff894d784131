"""Importance weights (step 5; open point 4), in logs."""

from __future__ import annotations

import numpy as np

from gslam.config import FilterConfig
from gslam.pointmap import FlatMaps, PointMap, segment_sum
from gslam.scan import Scan, transform_points


def log_weight_sum(q: np.ndarray, p_prev: np.ndarray, owner: np.ndarray, n: int) -> np.ndarray:
    """The paper's w_i = sum_j q_j p_{t-1}^j (denominator of eq. 7), in logs."""
    with np.errstate(divide="ignore"):
        return np.log(segment_sum(q * p_prev, owner, n))


def relative_probability(flat: FlatMaps, n: int, cfg: FilterConfig) -> np.ndarray:
    """p on a common scale across map semantics: p itself for the binary map, else p / mean p (<= 1)."""
    if cfg.map_update == "binary":
        return flat.p
    counts = np.bincount(flat.owner, minlength=n)
    mean_p = segment_sum(flat.p, flat.owner, n) / np.maximum(counts, 1)
    return np.minimum(flat.p / np.maximum(mean_p[flat.owner], 1e-300), 1.0)


def log_weight_beam_sum(
    flat: FlatMaps,
    r: np.ndarray,
    j: np.ndarray,
    z: np.ndarray,
    observed: np.ndarray,
    scan: Scan,
    n: int,
    cfg: FilterConfig,
) -> np.ndarray:
    """Each return is one observation: log w_i = tempering * sum over returns of
    log(floor + (1 - floor)(1 - exp(-s_ij))), s_ij the sum over the particle's points on beam j of
    p_k exp(-(r_k - z_j)^2 / 2 sigma^2)."""
    returns = scan.returns
    on_return = observed & returns[j]
    contrib = np.where(
        on_return, relative_probability(flat, n, cfg) * np.exp(-0.5 * ((r - z) / cfg.weight_sigma_m) ** 2), 0.0
    )
    b = scan.geometry.beam_count
    s = np.bincount(flat.owner * b + j, weights=contrib, minlength=n * b).reshape(n, b)
    idx = np.flatnonzero(returns)[:: cfg.weight_beam_stride]
    like = cfg.weight_floor + (1 - cfg.weight_floor) * (1 - np.exp(-s[:, idx]))
    return cfg.weight_tempering * np.log(like).sum(axis=1)


def endpoint_scores(m: PointMap, pose: np.ndarray, pts_sensor: np.ndarray, cfg: FilterConfig) -> np.ndarray:
    """Per return: the best Gaussian score exp(-d^2 / 2 sigma^2) x p of the map points near its end point."""
    if len(m) == 0:
        return np.zeros(len(pts_sensor))
    world = transform_points(pose, pts_sensor)
    k = min(3, len(m))
    dist, idx = m.tree.query(world, k=k, distance_upper_bound=3 * cfg.weight_sigma_m)
    dist = dist.reshape(len(world), -1)
    idx = np.minimum(idx.reshape(len(world), -1), len(m) - 1)
    p = m.p if cfg.map_update == "binary" else np.minimum(m.p / m.mean_p, 1.0)
    score = np.where(np.isfinite(dist), np.exp(-0.5 * (dist / cfg.weight_sigma_m) ** 2) * p[idx], 0.0)
    return score.max(axis=1)


def log_weight_likelihood_field(maps: list[PointMap], poses: np.ndarray, scan: Scan, cfg: FilterConfig) -> np.ndarray:
    """Each return is one observation scored against the nearest probable map points of the particle:
    log w_i = tempering * sum_j log(floor + (1 - floor) score_ij)."""
    _, z, b = scan.return_polar()
    sel = slice(None, None, cfg.weight_beam_stride)
    pts = np.column_stack([z[sel] * np.cos(b[sel]), z[sel] * np.sin(b[sel])])
    out = np.zeros(len(maps))
    for i, m in enumerate(maps):  # per particle: one KD-tree query over its returns
        s = endpoint_scores(m, poses[i], pts, cfg)
        out[i] = cfg.weight_tempering * np.log(cfg.weight_floor + (1 - cfg.weight_floor) * s).sum()
    return out
