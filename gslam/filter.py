"""The G-SLAM particle filter: the paper's six steps for one scan, vectorised over particles and points."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .config import FilterConfig
from .motion import wrap_angle
from .pointmap import (
    FlatMaps,
    PointMap,
    draw_new_points,
    interpolate_prior,
    point_likelihood_ratio,
    project,
    prune_and_thin,
    update_probabilities,
)
from .proposal import match_scans
from .resampling import continue_from_parents, effective_sample_size, reweight_and_resample
from .scan import Scan
from .trajectory import AncestryTree
from .weights import log_weight_beam_sum, log_weight_likelihood_field, log_weight_sum

Predictor = Callable[[np.ndarray, np.random.Generator | None], np.ndarray]
"""Step 1's motion model: (poses (N,3), rng) -> sampled poses (N,3); rng None: the noise-free motion."""


@dataclass
class StepResult:
    t_s: float
    poses: np.ndarray  # (N, 3) particle poses after the step (before resampling)
    weights: np.ndarray  # (N,) normalised importance weights
    effective_sample_size: float
    resampled: bool
    updated: bool  # False when the update schedule skipped this scan (prediction only)
    best: int
    best_pose: np.ndarray
    map_points: int  # in the best particle's map
    map_points_total: int
    matched: int  # particles whose scan match succeeded


class SlamFilter(Protocol):
    """What the pipeline needs of a SLAM method (G-SLAM, FastSLAM, ...)."""

    poses: np.ndarray
    weights: np.ndarray
    tree: AncestryTree

    def step(
        self, scan: Scan, predict: Predictor | None = None, intensities: np.ndarray | None = None
    ) -> StepResult: ...

    def best_particle(self) -> int: ...

    def best_trajectory(self) -> tuple[np.ndarray, np.ndarray]: ...

    def map_points(self, particle: int) -> tuple[np.ndarray, np.ndarray]: ...


class GSlamFilter:
    """N particles, each a pose, a pose history (shared ancestry tree) and a point map."""

    def __init__(self, cfg: FilterConfig, initial_pose: np.ndarray) -> None:
        self.cfg = cfg
        self.rng = np.random.default_rng(cfg.seed)
        n = cfg.particles
        self.poses = np.tile(np.asarray(initial_pose, dtype=float), (n, 1))
        if cfg.initial_sigma_xy_m > 0 or cfg.initial_sigma_phi_rad > 0:
            self.poses[:, :2] += self.rng.standard_normal((n, 2)) * cfg.initial_sigma_xy_m
            self.poses[:, 2] = wrap_angle(self.poses[:, 2] + self.rng.standard_normal(n) * cfg.initial_sigma_phi_rad)
        self.weights = np.full(n, 1.0 / n)
        self.maps: list[PointMap] = [PointMap.empty()] * n  # one shared empty map (copy-on-write)
        self.tree = AncestryTree()
        self.steps = 0
        self._last_update_pose: np.ndarray | None = None
        self._filled = self.poses.copy()  # noise-free motion since the last update (recorded for skipped scans)

    # ------------------------------------------------------------------------------------------
    def best_particle(self) -> int:
        return int(np.argmax(self.weights))

    def best_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        return self.tree.trajectory(self.best_particle())

    def map_points(self, particle: int) -> tuple[np.ndarray, np.ndarray]:
        """The particle's map as points (K, 2) with probabilities (K,)."""
        m = self.maps[particle]
        return m.xy, m.p

    def _due(self) -> bool:
        if self.cfg.update_schedule == "every_scan" or self._last_update_pose is None:
            return True
        best = self.poses[self.best_particle()]
        last = self._last_update_pose
        return bool(
            np.hypot(best[0] - last[0], best[1] - last[1]) >= self.cfg.min_travel_m
            or abs(wrap_angle(best[2] - last[2])) >= self.cfg.min_turn_rad
        )

    # ------------------------------------------------------------------------------------------
    def step(self, scan: Scan, predict: Predictor | None = None, intensities: np.ndarray | None = None) -> StepResult:
        """One G-SLAM step for scan z_t after the controls since the previous scan."""
        cfg, n = self.cfg, self.cfg.particles
        if cfg.min_range_m is not None and scan.min_range_m != cfg.min_range_m:
            scan = Scan(scan.t_s, scan.ranges_m, scan.geometry, cfg.min_range_m)
        # 1. Draw s_t^i from the motion model.
        if predict is not None:
            self.poses = predict(self.poses, self.rng)
            if cfg.fill_skipped == "odometry":
                self._filled = predict(self._filled, None)
        if not self._due():
            recorded = self._filled if cfg.fill_skipped == "odometry" else self.poses
            self.tree.record(scan.t_s, recorded)
            self.steps += 1
            best = self.best_particle()
            return StepResult(
                scan.t_s,
                self.poses.copy(),
                self.weights.copy(),
                effective_sample_size(self.weights),
                False,
                False,
                best,
                recorded[best].copy(),
                len(self.maps[best]),
                sum(len(m) for m in self.maps),
                0,
            )
        matched = 0
        if cfg.proposal == "scan_match":
            matched = self._scan_match_proposal(scan)

        flat = FlatMaps.of(self.maps)
        # 2. Generate new points around the returns (drawn z_hat, inverse of g, interpolated prior).
        new_owner, new_xy, new_q, _ = draw_new_points(self.poses, scan, cfg, self.rng)
        new_prior = interpolate_prior(self.maps, new_owner, new_xy, cfg) if len(new_owner) else np.empty(0)
        # 3. q of existing points (eq. 6) and the update of eq. 7 over existing and new points.
        r, j, z, observed, free = project(flat, self.poses, scan, cfg.free_space_beams)
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
        else:
            log_like = log_weight_likelihood_field(self.maps, self.poses, scan, cfg)
        if flat.p.size == 0:
            log_like = np.zeros(n)  # first scan: nothing to compare with
        p_new = update_probabilities(all_prev, all_q, all_owner, all_observed, n, cfg)
        # 4. Remove meaningless points (and thin dense cells).
        pruned = prune_and_thin(FlatMaps(all_xy, p_new, all_owner), n, cfg)
        self.maps = pruned.split(n)
        # 6. Weights, effective sample size, resampling (RSR).
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
            len(self.maps[best]),
            len(pruned.p),
            matched,
        )
        self.tree.record(scan.t_s, self.poses)
        if parents is not None:
            self.poses, self.maps, self.weights = continue_from_parents(parents, self.poses, self.maps, self.tree)
            result.resampled = True
        self._last_update_pose = self.poses[self.best_particle()].copy()
        self._filled = self.poses.copy()
        self.steps += 1
        return result

    def _scan_match_proposal(self, scan: Scan) -> int:
        """Open point 6: refine every particle's motion-model sample by matching the scan against its own
        map (`proposal.match_scans`), then sample around the match."""
        cfg, n = self.cfg, self.cfg.particles
        _, z, b = scan.return_polar()
        sel = slice(None, None, cfg.weight_beam_stride)
        pts = np.column_stack([z[sel] * np.cos(b[sel]), z[sel] * np.sin(b[sel])])
        poses, matched, _ = match_scans(self.maps, self.poses, pts, cfg)
        noise = self.rng.standard_normal((n, 3)) * [
            cfg.proposal_sigma_xy_m,
            cfg.proposal_sigma_xy_m,
            cfg.proposal_sigma_phi_rad,
        ]
        poses[matched] += noise[matched]
        poses[:, 2] = wrap_angle(poses[:, 2])
        self.poses = poses
        return int(matched.sum())
