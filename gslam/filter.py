"""The G-SLAM particle filter: the paper's six steps for one scan, vectorised over particles and points."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from gslam import mapupdate
from gslam.ancestry import AncestryTree
from gslam.backend import BackEndSettings, PoseGraphBackEnd, PreviousGraph
from gslam.config import FilterConfig
from gslam.motion import wrap_angle, wrap_angle_scalar
from gslam.placement import Placement, PlacementLimits, Retrack, place_scans
from gslam.pointmap import MAP_DTYPE, PointMap, cell_keys, distinct_maps
from gslam.resampling import continue_from_parents, effective_sample_size, reweight_and_resample
from gslam.scan import Scan
from gslam.scanmatch import MatchSettings, MatchWorkspace, match_and_weigh
from gslam.se2 import between_scalar

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

    def __init__(self, cfg: FilterConfig, initial_pose: np.ndarray, threads: int | None = None) -> None:
        self.cfg = cfg
        self._workspace = MatchWorkspace(threads or 1)
        self.map_update = mapupdate.select(cfg, threads or 1)
        """Steps 2 to 4 (and the weights computed with them): compiled and local to the scan where that
        implementation supports the settings, else numpy over whole maps (`gslam.mapupdate`)."""
        self.rng = np.random.default_rng(cfg.seed)
        n = cfg.particles
        self.poses = np.tile(np.asarray(initial_pose, dtype=float), (n, 1))
        if cfg.initial_sigma_xy_m > 0 or cfg.initial_sigma_phi_rad > 0:
            self.spread_poses(cfg.initial_sigma_xy_m, cfg.initial_sigma_phi_rad)
        self.weights = np.full(n, 1.0 / n)
        self._summary_of: np.ndarray | None = None  # the weights `_summary` is of
        self._summary = (float(n), 0)
        self.maps: list[PointMap] = [PointMap.empty()] * n  # one shared empty map (copy-on-write)
        self._points_total = 0  # points in all the maps (they change only at updates)
        self._layout: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        """When every map is a slice of one buffer (after a compiled update): (xy, p, lo, hi), particle i's
        map being xy[lo[i]:hi[i]]; the matcher and the update then read the buffer without copying it."""
        self.tree = AncestryTree()
        self.steps = 0
        self._last_update_pose: np.ndarray | None = None
        self._filled = self.poses.copy()  # noise-free motion since the last update (recorded for skipped scans)
        self._travel_m = 0.0  # path length and turn of the noise-free motion since the last update
        self._recheck = False  # the last update's match disagreed with the motion (recheck_ratio)
        self.rechecked_updates = 0
        """Updates that came early, after recheck_travel_m or recheck_turn_rad (recheck_ratio)."""
        self._turn_rad = 0.0
        self._fit_reference = 0.0  # median fit (score per return) of the previous update's matches
        self.heading_noise_scale = 1.0
        """The factor on the motion model's heading noise (`motion_noise_adaptive`), learnt from the matches."""
        # the running mean of (error / model sd)^2; 1: the model holds until the matches show otherwise
        self._heading_error_ratio2 = 1.0
        self._heading_noise = np.zeros(n)  # the model's heading noise drawn since the last update, unscaled
        self._updated: list[bool] = []  # per step: whether it updated the maps (its poses were matched)
        self._motion: list[tuple[float, float, float]] = []
        """Per step: the noise-free motion from the scan before (in its frame), whatever the filter did."""
        self._corrected_map: tuple[int, np.ndarray, np.ndarray] | None = None
        """(particle, points, p): the best particle's map moved with the pose graph (`close_loops`)."""
        self._seeded: tuple[np.ndarray, np.ndarray] | None = None
        """(position keys, saved p) of the points `seed_map` capped (to `continue_max_p`), sorted by key."""
        self.placed: tuple[np.ndarray, np.ndarray] | None = None
        """(times, poses) of the best particle's trajectory with every scan placed by its final map
        (`place_every_scan`); `best_trajectory()` gives it once set."""

    # ------------------------------------------------------------------------------------------
    def best_particle(self) -> int:
        return int(np.argmax(self.weights))

    def _weights_summary(self) -> tuple[float, int]:
        """(effective sample size, best particle) of the weights, kept until the weights are replaced (they
        change at updates only, and are always replaced, never written in place)."""
        w = self.weights
        if self._summary_of is not w:
            self._summary = (effective_sample_size(w), self.best_particle())
            self._summary_of = w
        return self._summary

    def best_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """The best particle's pose at every scan: as recorded, or placed by its final map once
        `place_every_scan` has run."""
        if self.placed is not None:
            return self.placed
        return self.tree.trajectory(self.best_particle())

    def spread_poses(self, sigma_xy_m: float, sigma_phi_rad: float) -> None:
        """Spread the particles' poses by independent normal draws (sd; m, rad) from the filter's generator:
        a start known only so well (`initial_sigma_*`; a continued run's start carried back by the odometry)."""
        n = len(self.poses)
        self.poses[:, :2] += self.rng.standard_normal((n, 2)) * sigma_xy_m
        self.poses[:, 2] = wrap_angle(self.poses[:, 2] + self.rng.standard_normal(n) * sigma_phi_rad)

    def place_every_scan(
        self,
        scans: Callable[[int, int], Iterable[Scan]],
        workers: int = 1,
        progress: Callable[[int, int], None] | None = None,
    ) -> Placement:
        """Match every scan of the run against the best particle's final map (`gslam.placement`);
        `best_trajectory()` then gives the placed poses. `scans(a, b)`: the run's scans a to b - 1 (the ones
        given to `step`, in order); `workers` threads place parts of the run at once. The maps and the
        particles are not changed."""
        cfg = self.cfg
        best = self.best_particle()
        times, recorded = self.tree.trajectory(best)
        xy, p = self.map_points(best)
        settings = self.placement_matcher()
        limits = PlacementLimits(
            min_hit_fraction=cfg.place_min_hit_fraction,
            max_shift_m=cfg.place_max_shift_m,
            max_turn_rad=cfg.place_max_turn_rad,
        )

        def ends(a: int, b: int) -> Iterable[tuple[np.ndarray, float]]:
            for scan in scans(a, b):
                scan = self._as_observed(scan)
                yield _end_points(scan), scan.geometry.angle_increment_rad

        anchored = np.asarray(self._updated, dtype=bool)
        motion = np.asarray(self._motion, dtype=float).reshape(-1, 3)
        search = MatchSettings.from_config(cfg)
        placement = place_scans(
            xy,
            p,
            recorded,
            ends,
            settings,
            limits,
            anchored,
            workers,
            progress,
            motion,
            times,
            search,
            rasters=cfg.place_rasters,
            retrack=Retrack(cfg.place_retrack_m, cfg.place_retrack_rad) if cfg.place_retrack else None,
        )
        self.placed = (times, placement.poses)
        return placement

    def placement_matcher(self) -> MatchSettings:
        """The matcher of the placement (the update's, with the place_* settings)."""
        cfg = self.cfg
        return replace(
            MatchSettings.from_config(cfg),
            step_xy_m=cfg.place_step_xy_m,
            step_phi_rad=cfg.place_step_phi_rad,
            levels=cfg.place_levels,
            climb_stride=cfg.place_climb_stride,
            fine_levels=min(cfg.match_fine_levels, cfg.place_levels + 1),
        )

    def seed_map(self, xy: np.ndarray, p: np.ndarray) -> None:
        """Start every particle's map from a map built before (`gslam process --continue`): points (K, 2)
        and their probabilities (K,), each p capped at `continue_max_p` so that this run's own returns
        replace the old points where it sees a place again. The map keeps one point per cell
        (`cell_size_m`), the most probable one where a saved map, moved by its pose graph, holds several;
        sorted by cell as the updates keep it."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        saved = np.asarray(p, dtype=float).reshape(-1)
        p = np.minimum(saved, self.cfg.continue_max_p)
        keys = cell_keys(xy, self.cfg.cell_size_m)
        order = np.lexsort((-p, keys))  # by cell, the most probable first
        keys, xy, p, saved = keys[order], xy[order], p[order], saved[order]
        first = np.ones(len(keys), dtype=bool)
        first[1:] = keys[1:] != keys[:-1]
        if self.cfg.max_points_per_cell > 1:
            rank = np.arange(len(keys)) - np.maximum.accumulate(np.where(first, np.arange(len(keys)), 0))
            first = rank < self.cfg.max_points_per_cell
        seeded = PointMap(
            np.ascontiguousarray(xy[first], dtype=MAP_DTYPE), np.ascontiguousarray(p[first], dtype=MAP_DTYPE)
        )
        self.maps = [seeded] * self.cfg.particles
        self._layout = None
        self._points_total = len(seeded) * self.cfg.particles
        saved = saved[first].astype(MAP_DTYPE)
        capped = saved > seeded.p
        point_keys = _point_keys(seeded.xy[capped])
        by_key = np.argsort(point_keys)
        self._seeded = (point_keys[by_key], saved[capped][by_key])

    def restore_saved_p(self) -> int:
        """At the run's end, before its map is saved: put every seeded point that this run never updated (the
        same position and the capped p, bit for bit) back at the p it was saved with, in the best particle's
        map. The cap (`seed_map`) is for this run's matching and updates, not a belief of its own: a place
        only an earlier run saw keeps its walls in the saved map and the occupancy grid (whose threshold,
        0.65, is above the cap). Done once, not at every `map_points` (the run's map snapshots show the map
        as the filter holds it). Returns how many points it put back."""
        if self._seeded is None or len(self._seeded[0]) == 0:
            return 0
        keys, saved_p = self._seeded
        self._seeded = None
        best = self.best_particle()
        m = self.maps[best]
        if len(m) == 0:
            return 0
        point_keys = _point_keys(m.xy)
        at = np.minimum(np.searchsorted(keys, point_keys), len(keys) - 1)
        untouched = (keys[at] == point_keys) & (m.p == MAP_DTYPE(self.cfg.continue_max_p))
        if not untouched.any():
            return 0
        p = np.array(m.p, copy=True)
        p[untouched] = saved_p[at[untouched]]
        self.maps = list(self.maps)
        self.maps[best] = PointMap(np.array(m.xy, copy=True), p)
        self._layout = None  # the best particle's map is no longer a slice of the buffer
        return int(untouched.sum())

    def close_loops(
        self,
        scans: Callable[[list[int]], Iterable[Scan]],
        settings: BackEndSettings | None = None,
        previous: PreviousGraph | None = None,
        first_session: int = 0,
    ) -> PoseGraphBackEnd:
        """The pose graph under the best particle's trajectory (placed, if `place_every_scan` ran) closed by
        loop closures (`gslam.backend`); where the graph corrects the front end (`PoseGraphBackEnd.applied`),
        `best_trajectory()` then gives the optimised trajectory and `map_points(best)` the best particle's
        map moved with it (each point with the node whose scan returns lie nearest it). `scans(steps)`: the
        run's scans at those steps (increasing). The maps and the particles are not changed. `previous`: the
        graph of the earlier mapping runs this one continues, whose nodes the graph starts with
        (`PoseGraphBackEnd.add_previous`); `first_session`: this run's number where it continues none."""
        best = self.best_particle()
        times, front = self.best_trajectory()
        backend = PoseGraphBackEnd(settings or BackEndSettings(), first_session)
        if previous is not None:
            backend.add_previous(*previous)
        steps = backend.node_steps(front)
        for step, scan in zip(steps, scans(list(steps)), strict=True):
            backend.add_node(step, front[step], self.node_points(scan))
        backend.finish()
        if backend.applied:  # else the closures confirm the front end: its trajectory and map stand
            xy, p = self.map_points(best)
            moved = backend.correct_points(np.asarray(xy, dtype=float))
            self.placed = (times, backend.correct_trajectory(front))
            self._corrected_map = (best, moved.astype(np.asarray(xy).dtype), p)
        return backend

    def node_points(self, scan: Scan) -> np.ndarray:
        """The scan's returns as the back end takes them (`gslam.backend`): the end points (K, 2), in the
        sensor frame, of the returns the filter observes."""
        return _end_points(self._as_observed(scan))

    def map_points(self, particle: int) -> tuple[np.ndarray, np.ndarray]:
        """The particle's map as points (K, 2) with probabilities (K,); the best particle's moved with the
        pose graph once `close_loops` has run."""
        if self._corrected_map is not None and self._corrected_map[0] == particle:
            return self._corrected_map[1], self._corrected_map[2]
        m = self.maps[particle]
        return m.xy, m.p

    def _due(self) -> bool:
        """Open point 7: update every scan, or (travel) once the motion since the last update, summed
        along the way from the odometry or controls without noise, reaches min_travel_m of path or
        min_turn_rad of turning (GMapping's linearUpdate / angularUpdate): the decision depends on how
        the vehicle moved, not on the particles' noise."""
        cfg = self.cfg
        if cfg.update_schedule == "every_scan" or self._last_update_pose is None:
            return True
        if self._recheck:
            return self._travelled(cfg.recheck_travel_m, cfg.recheck_turn_rad)
        return self._travelled(cfg.min_travel_m, cfg.min_turn_rad)

    def _travelled(self, travel_m: float, turn_rad: float) -> bool:
        """The noise-free motion since the last update reached travel_m of path or turn_rad of turning."""
        return self._travel_m >= travel_m or self._turn_rad >= turn_rad

    def _travelled_far(self) -> int:
        """1 where the noise-free travel since the last update reaches match_coarse_deeper_travel_m."""
        far = self.cfg.match_coarse_deeper_travel_m
        return int(far > 0 and self._travelled(far, math.inf))

    def _disagrees(self) -> bool:
        """`recheck_ratio`: the update's matched poses (the particles' median) moved further from the
        noise-free motion since the last update than the motion itself can be off where the odometry holds."""
        cfg = self.cfg
        if cfg.recheck_ratio <= 0 or cfg.update_schedule == "every_scan":
            return False
        shift = float(np.median(np.hypot(*(self.poses[:, :2] - self._filled[:, :2]).T)))
        turn = float(np.median(np.abs(wrap_angle(self.poses[:, 2] - self._filled[:, 2]))))
        return (
            shift > cfg.recheck_ratio * self._travel_m + cfg.recheck_travel_m
            or turn > cfg.recheck_ratio * self._turn_rad + cfg.recheck_turn_rad
        )

    def _as_observed(self, scan: Scan) -> Scan:
        """The scan as the filter observes it: returns nearer than min_range_m or beyond usable_range_m
        are not observations."""
        cfg = self.cfg
        if cfg.min_range_m is not None and scan.min_range_m != cfg.min_range_m:
            scan = Scan(scan.t_s, scan.ranges_m, scan.geometry, cfg.min_range_m)
        if cfg.usable_range_m is not None and cfg.usable_range_m < scan.geometry.max_range_m:
            # Beyond it nothing is observed and free space ends there (GMapping's maxUrange).
            usable = replace(scan.geometry, max_range_m=cfg.usable_range_m)
            scan = Scan(scan.t_s, scan.ranges_m, usable, scan.min_range_m)
        return scan

    # ------------------------------------------------------------------------------------------
    def step(self, scan: Scan, predict: Predictor | None = None, intensities: np.ndarray | None = None) -> StepResult:
        """One G-SLAM step for scan z_t after the controls since the previous scan."""
        cfg = self.cfg
        scan = self._as_observed(scan)
        # 1. Draw s_t^i from the motion model.
        if predict is not None:
            if cfg.motion_noise_adaptive:
                exact = predict(self.poses, None)
                sampled = predict(self.poses, self.rng)
                noise = wrap_angle(sampled[:, 2] - exact[:, 2])
                self._heading_noise += noise
                if self.heading_noise_scale != 1.0:
                    sampled[:, 2] = wrap_angle(exact[:, 2] + self.heading_noise_scale * noise)
                self.poses = sampled
            else:
                self.poses = predict(self.poses, self.rng)
            before = self._filled[0].tolist()
            self._filled = predict(self._filled, None)
            after = self._filled[0].tolist()
            self._travel_m += float(np.hypot(after[0] - before[0], after[1] - before[1]))
            self._turn_rad += abs(wrap_angle_scalar(after[2] - before[2]))
            self._motion.append(between_scalar(before, after))
        else:
            self._motion.append((0.0, 0.0, 0.0))
        if not self._due():
            recorded = self._filled if cfg.fill_skipped == "odometry" else self.poses
            self.tree.record(scan.t_s, recorded)
            self._updated.append(False)
            self.steps += 1
            ess, best = self._weights_summary()
            return StepResult(
                scan.t_s,
                self.poses.copy(),
                self.weights.copy(),
                ess,
                False,
                False,
                best,
                recorded[best].copy(),
                len(self.maps[best]),
                self._points_total,
                0,
            )
        if self._recheck and not self._travelled(cfg.min_travel_m, cfg.min_turn_rad):
            self.rechecked_updates += 1
        layout = self._layout if self._layout is not None else distinct_maps(self.maps)
        matched, matched_log_like = self._match_and_weigh(scan, layout)
        recheck = self._disagrees()
        if cfg.motion_noise_adaptive and 2 * matched >= cfg.particles:
            self._adapt_heading_noise()
        # 2 to 5. New points, the update of eq. 7, pruning; the importance factors.
        self.maps, self._layout, log_like, map_points_total = self.map_update(
            self.maps, layout, self.poses, scan, self.rng, matched_log_like
        )
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
            map_points_total,
            matched,
        )
        self.tree.record(scan.t_s, self.poses)
        self._updated.append(True)
        if parents is not None:
            self.poses, self.maps, self.weights = continue_from_parents(parents, self.poses, self.maps, self.tree)
            if self._layout is not None:
                xy, p, lo, hi = self._layout
                self._layout = (xy, p, lo[parents], hi[parents])
            result.resampled = True
        self._last_update_pose = self.poses[self.best_particle()].copy()
        self._heading_noise = np.zeros(len(self.poses))
        self._filled = self.poses.copy()
        self._travel_m = self._turn_rad = 0.0
        self._recheck = recheck
        self._points_total = sum(len(m) for m in self.maps)  # until the next update
        self.steps += 1
        return result

    def _adapt_heading_noise(self) -> None:
        """`motion_noise_adaptive`: compare the odometry's heading error that the matches found since the last
        update (the median over the particles of matched minus noise-free heading) with the heading noise
        the motion model drew (its sd over the particles, unscaled); keep the running mean of the squared
        ratio over the last `motion_noise_window` updates (each update's ratio clipped at `motion_noise_clip` x
        the running one: robust to a single slip), and scale the model's heading noise by
        `motion_noise_safety` x its square root, within [`motion_noise_min_scale`, 1]."""
        cfg = self.cfg
        model_sd = float(np.sqrt(np.mean(self._heading_noise**2)))
        if model_sd < 1e-9:
            return  # no motion, nothing drawn
        error = float(np.median(wrap_angle(self.poses[:, 2] - self._filled[:, 2])))
        alpha = 1.0 / cfg.motion_noise_window
        ratio2 = (error / model_sd) ** 2
        if cfg.motion_noise_clip > 0:
            # Huber-type: an outlier (a slip the matcher corrected) moves the mean by a bounded step
            level = max(self._heading_error_ratio2, (cfg.motion_noise_min_scale / cfg.motion_noise_safety) ** 2)
            ratio2 = min(ratio2, cfg.motion_noise_clip**2 * level)
        self._heading_error_ratio2 += alpha * (ratio2 - self._heading_error_ratio2)
        scale = cfg.motion_noise_safety * math.sqrt(self._heading_error_ratio2)
        self.heading_noise_scale = min(1.0, max(cfg.motion_noise_min_scale, scale))

    def _match_and_weigh(self, scan: Scan, layout: tuple[np.ndarray, ...]) -> tuple[int, np.ndarray]:
        """Open point 6: refine every particle's motion-model sample by matching the scan against its own
        map (`scanmatch.match_and_weigh`), then sample around the match; and the scan's log-likelihood
        at the resulting pose (the "matched_field" weight). Returns (particles matched, log-likelihoods)."""
        cfg, n = self.cfg, self.cfg.particles
        if cfg.proposal != "scan_match" and cfg.weighting != "matched_field":
            return 0, np.zeros(n)
        pts = _end_points(scan, cfg.weight_beam_stride)
        xy, p, lo, hi = layout
        climb = cfg.proposal == "scan_match"
        args = MatchSettings.from_config(cfg).arguments(scan.geometry.angle_increment_rad)
        if not climb:
            args["max_iterations"] = 0  # weigh at the motion samples
        poses, score, log_like, hits = match_and_weigh(
            xy,
            p,
            lo,
            hi,
            self.poses,
            pts,
            workspace=self._workspace,
            coarse_factor=cfg.match_coarse_factor,
            coarse_levels=cfg.match_coarse_levels,
            coarse_stride=cfg.match_coarse_stride,
            coarse_min_gain=cfg.match_coarse_min_gain,
            coarse_depth=cfg.match_coarse_depth + self._travelled_far(),
            coarse_gate=cfg.match_coarse_gate,
            coarse_reference=self._fit_reference,
            **args,
        )
        if not climb:
            return 0, log_like
        self._fit_reference = float(np.median(score)) / max(1, len(pts))
        matched = (score > cfg.match_min_score * len(pts)) & (hits > 0)
        noise = self.rng.standard_normal((n, 3)) * [
            cfg.proposal_sigma_xy_m,
            cfg.proposal_sigma_xy_m,
            cfg.proposal_sigma_phi_rad,
        ]
        poses[matched] += noise[matched]
        poses[:, 2] = wrap_angle(poses[:, 2])
        self.poses = np.where(matched[:, None], poses, self.poses)
        return int(matched.sum()), log_like


def _point_keys(xy: np.ndarray) -> np.ndarray:
    """One int64 per map point (K, 2): its two coordinates' bits as stored (`MAP_DTYPE`), so that a point
    is found again only where it was not moved."""
    return np.ascontiguousarray(xy, dtype=MAP_DTYPE).view(np.int64).reshape(-1)


def _end_points(scan: Scan, stride: int = 1) -> np.ndarray:
    """Every `stride`-th return's end point (K, 2) in the sensor frame."""
    _, z, b = scan.return_polar()
    sel = slice(None, None, stride)
    return np.column_stack([z[sel] * np.cos(b[sel]), z[sel] * np.sin(b[sel])])
