"""Monte Carlo localisation in a fixed map: KLD-adaptive particle count, the scan-matching proposal and
recovery from kidnapping (augmented MCL), vectorised over particles.

One step per scan, as the SLAM filter: the odometry moves every particle (the same motion model,
`gslam.motion.apply_odometry`); once the robot has moved `update_travel_m` or turned `update_turn_rad`
since the last update, the scan updates the particles:

1. the scan-matching proposal: each particle climbs the likelihood field from its motion sample
   (`gslam.localise.match.climb`), as GMapping's particles climb their maps;
2. the importance weight: the scan's likelihood at the climbed pose (likelihood field with a uniform part,
   on `weight_beams` returns spread over the scan, AMCL's max_beams);
3. recovery: augmented MCL (Thrun, Burgard & Fox 2005, Table 8.3): short- and long-term averages of the
   likelihood per return, w_fast and w_slow; when the short one falls below the long one the scan no
   longer fits where the particles are, and a share max(0, 1 - w_fast / w_slow) of the new particles is
   drawn uniformly over the map's free space; and while the scan fits poorly at the estimate
   (`tracking_fitness`), `lost_particles` more are drawn there at every update;
4. KLD resampling (Fox 2003): particles are drawn until their count exceeds the bound for the number of
   histogram bins they fill, so a converged filter runs on a few hundred and a global search on thousands.

The estimate is the weighted mean of the main cluster (the particles near the heaviest one); the filter
says it is tracking when that cluster holds most of the weight, is tight, and the scan fits the map there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from dataclasses import field as dataclass_field

import numpy as np

from gslam.config import check_fields
from gslam.localise.field import LikelihoodField
from gslam.localise.match import ScanModel, climb, log_likelihood
from gslam.motion import apply_odometry, wrap_angle


@dataclass
class LocaliseConfig:
    """Monte Carlo localisation settings, with documented defaults."""

    seed: int = 0
    global_particles: int = 20_000
    """Particles spread uniformly over the free space when no initial pose is given (first update)."""
    min_particles: int = 100
    """KLD sampling's least count (AMCL min_particles)."""
    max_particles: int = 5_000
    """KLD sampling's largest count after the first update (AMCL max_particles)."""
    kld_epsilon: float = 0.05
    """KLD sampling: the bound on the error between the sample and the true posterior (AMCL kld_err)."""
    kld_z: float = 2.326
    """KLD sampling: upper standard normal quantile of the confidence 1 - delta (0.99; AMCL kld_z)."""
    kld_bin_xy_m: float = 0.5
    """KLD sampling: histogram bin size in x and y."""
    kld_bin_rad: float = math.radians(10.0)
    """KLD sampling: histogram bin size in heading."""
    initial_sigma_xy_m: float = 0.5
    """With an initial pose: spread of the particles (sd) in x and y."""
    initial_sigma_rad: float = math.radians(15.0)
    """With an initial pose: spread of the particles (sd) in heading."""
    initial_particles: int = 2_000
    """With an initial pose: particles drawn around it."""
    odom_sigma: tuple[float, float, float, float] = (0.1, 0.2, 0.1, 0.2)
    """Odometry noise (srr, srt, str, stt), as the SLAM filter's (`FilterConfig.odom_sigma`)."""
    update_travel_m: float = 0.2
    """Update after this much travel since the last update (AMCL update_min_d)."""
    update_turn_rad: float = math.radians(30.0)
    """... or this much turning (AMCL update_min_a)."""
    match_sigma_m: float = 0.05
    """Width of the climb's score (the SLAM matcher's match_sigma_m)."""
    match_step_xy_m: float = 0.05
    """First climbing step in x and y (GMapping lstep), halved `match_levels` times."""
    match_step_rad: float = 0.05
    """First climbing step in heading (GMapping astep)."""
    match_levels: int = 5
    """Step halvings of the climb."""
    match_beams: int = 60
    """Returns used by the climb (spread evenly over the scan)."""
    min_returns: int = 20
    """A scan with fewer returns says too little to update on: the particles move on odometry alone and the
    filter does not claim to track (open space, a blinded laser)."""
    weight_beams: int = 60
    """Returns used by the weight and the fitness (AMCL max_beams)."""
    weight_sigma_m: float = 0.2
    """Width of the likelihood field of the weight (AMCL sigma_hit)."""
    z_hit: float = 0.95
    """Likelihood-field mixture: the part explained by the map (AMCL z_hit)."""
    z_rand: float = 0.05
    """... and the uniform part (AMCL z_rand; per return, here a constant added to z_hit exp(-d^2/2s^2))."""
    alpha_slow: float = 0.001
    """Augmented MCL: rate of the long-term likelihood average (AMCL recovery_alpha_slow)."""
    alpha_fast: float = 0.1
    """Augmented MCL: rate of the short-term average (AMCL recovery_alpha_fast)."""
    lost_particles: int = 2_000
    """While the scan does not fit at the estimate (fitness below tracking_fitness), this many particles are
    added at each update, drawn over the free space: augmented MCL alone needs the fit to fall from a good
    long-term average, and a start at a wrong pose never had one."""
    cluster_xy_m: float = 1.0
    """The main cluster: particles within this distance ..."""
    cluster_rad: float = math.radians(20.0)
    """... and this heading of the heaviest particle."""
    tracking_weight: float = 0.8
    """Tracking needs the main cluster to hold at least this share of the weight ..."""
    tracking_sigma_xy_m: float = 0.3
    """... its position spread (sd, the larger axis) at most this ..."""
    tracking_sigma_rad: float = math.radians(5.0)
    """... its heading spread (sd) at most this ..."""
    tracking_fitness: float = 0.9
    """... and the scan's fitness at the estimate (the share of returns the map explains) at least this.
    Measured, localising a log in its own map: 0.95 (mit-csail) and 0.91 (intel) at the 0.1 % quantile of
    the updates (people walk by); wrong poses that the filter settled on in the half of mit-csail's map
    that the robot had not mapped yet fitted 0.80 to 0.84, a scan of a place the map does not hold fits
    a corridor map at up to 0.7."""

    confirm_travel_m: float = 3.0
    """A new hypothesis (an estimate that jumped: farther from the last update's than the travel between them
    plus `cluster_xy_m`, or the first from a global start) is claimed as tracking only once it has met the
    tests above at its updates over this much travel. Between the updates that meet them the estimate must
    not jump; updates that fail them report lost but keep the count. An initial pose given by the user is a
    confirmed hypothesis. A place that looks like another for a few metres no longer passes for it:
    localising the second half of a log in the map of its first half, claims of tracking more than 0.5 m
    off were 8 % (mit-csail), 10 % (intel), 16 % (fr079) and 14 % (belgioioso) of the tracked scans, and
    none with 3 m (2 m: 0.5 % and 2 %). It changes what the filter claims, not its particles."""

    def __post_init__(self) -> None:
        check_fields(self, _LIMITS)
        if self.min_particles > self.max_particles:
            raise ValueError("min_particles must not exceed max_particles")


_LIMITS = {
    "seed": (0, 2**63, True),
    "global_particles": (1, 10_000_000, True),
    "min_particles": (1, 10_000_000, True),
    "max_particles": (1, 10_000_000, True),
    "initial_particles": (1, 10_000_000, True),
    "kld_epsilon": (0, 1, False),
    "match_levels": (0, 30, True),
    "match_beams": (1, 100_000, True),
    "weight_beams": (1, 100_000, True),
    "z_hit": (0, 1, True),
    "z_rand": (0, 1, False),
    "alpha_slow": (0, 1, False),
    "alpha_fast": (0, 1, False),
    "lost_particles": (0, 10_000_000, True),
    "tracking_weight": (0, 1, True),
    "tracking_fitness": (0, 1, True),
    "confirm_travel_m": (0, math.inf, True),
}


@dataclass
class LocaliseStep:
    """What one scan gave."""

    t_s: float
    pose: np.ndarray
    """(3,) the estimate: weighted mean of the main cluster."""
    covariance: np.ndarray
    """(3, 3) covariance of the main cluster (x, y, heading)."""
    particles: int
    updated: bool
    """False: the robot had not moved enough since the last update; prediction only."""
    tracking: bool
    """The filter's own verdict: converged on one pose that fits the scan (else lost, or still searching)."""
    fitness: float
    """Share of the scan's returns the map explains at the estimate (mean exp(-d^2 / 2 weight_sigma^2));
    carried over from the last update on prediction-only steps."""
    cluster_weight: float
    injected: int
    """Particles drawn afresh over the free space at this update (recovery)."""
    w_fast: float = 0.0
    w_slow: float = 0.0


@dataclass
class _Averages:
    slow: float = 0.0
    fast: float = 0.0


def kld_count(bins: np.ndarray, epsilon: float, z: float) -> np.ndarray:
    """Fox's bound on the number of particles for k occupied bins (elementwise; k <= 1 gives 1)."""
    k1 = np.maximum(np.asarray(bins, dtype=float) - 1.0, 1e-12)
    a = 2.0 / (9.0 * k1)
    return np.where(bins > 1, k1 / (2 * epsilon) * (1.0 - a + np.sqrt(a) * z) ** 3, 1.0)


def kld_resample(
    poses: np.ndarray, weights: np.ndarray, rng: np.random.Generator, cfg: LocaliseConfig, max_count: int
) -> np.ndarray:
    """Indices of the resampled particles: i.i.d. draws from `weights`, as many as KLD sampling takes (the
    first m draws where m reaches the bound for the bins those m fill; within [min_particles, max_count])."""
    draws = rng.choice(len(weights), size=max_count, p=weights)
    ix = np.floor(poses[draws, 0] / cfg.kld_bin_xy_m).astype(np.int64)
    iy = np.floor(poses[draws, 1] / cfg.kld_bin_xy_m).astype(np.int64)
    ih = np.floor((poses[draws, 2] + math.pi) / cfg.kld_bin_rad).astype(np.int64)
    ix -= ix.min()
    iy -= iy.min()
    key = (ix * (int(iy.max()) + 1) + iy) * (int(ih.max()) + 1) + ih  # one integer per bin
    _, first = np.unique(key, return_index=True)
    new = np.zeros(max_count, dtype=bool)
    new[first] = True
    k = np.cumsum(new)  # bins filled by the first m + 1 draws
    m = np.arange(1, max_count + 1)
    bound = kld_count(np.arange(int(k[-1]) + 1), cfg.kld_epsilon, cfg.kld_z)  # by bin count, looked up
    enough = (m >= bound[k]) & (m >= cfg.min_particles)
    count = int(np.argmax(enough)) + 1 if enough.any() else max_count
    return draws[:count]


def _subsample(points: np.ndarray, count: int) -> np.ndarray:
    if len(points) <= count:
        return points
    return points[np.linspace(0, len(points) - 1, count).round().astype(int)]


@dataclass
class MonteCarloLocaliser:
    """The particle filter over poses in `field`'s map (laser poses: the map's frame is the laser's)."""

    field: LikelihoodField
    cfg: LocaliseConfig = dataclass_field(default_factory=LocaliseConfig)
    initial_pose: np.ndarray | None = None
    initial_sigma: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        cfg = self.cfg
        self.rng = np.random.default_rng(cfg.seed)
        self.model = ScanModel(self.field, cfg.match_sigma_m, cfg.weight_sigma_m, cfg.z_hit, cfg.z_rand)
        if self.initial_pose is None:
            self.poses = self.field.sample_free(cfg.global_particles, self.rng)
        else:
            sxy, sphi = self.initial_sigma or (cfg.initial_sigma_xy_m, cfg.initial_sigma_rad)
            n = cfg.initial_particles
            self.poses = np.tile(np.asarray(self.initial_pose, dtype=float), (n, 1))
            self.poses[:, :2] += self.rng.standard_normal((n, 2)) * sxy
            self.poses[:, 2] = wrap_angle(self.poses[:, 2] + self.rng.standard_normal(n) * sphi)
        self.weights = np.full(len(self.poses), 1.0 / len(self.poses))
        self._avg = _Averages()
        self._averaging = False
        self._anchor = 0
        self._travel_m = math.inf  # update at the first scan
        self._turn_rad = 0.0
        self._last = LocaliseStep(0.0, self.poses[0].copy(), np.eye(3), len(self.poses), False, False, 0.0, 0.0, 0)
        self.updates = 0
        # The hypothesis the estimate follows (`confirm_travel_m`): its estimate at the last update and the
        # travel over which it met the tracking tests. The user's initial pose is one already confirmed.
        self._hypothesis = None if self.initial_pose is None else np.asarray(self.initial_pose, dtype=float).copy()
        self._confirmed_m = cfg.confirm_travel_m if self.initial_pose is not None else 0.0

    # ------------------------------------------------------------------------------------------
    def predict(self, delta: tuple[float, float, float]) -> None:
        """Move every particle by the odometry's motion `delta` (dx, dy, dtheta in the previous pose's frame)."""
        self.poses = apply_odometry(self.poses, delta, self.rng, self.cfg.odom_sigma)
        self._travel_m += math.hypot(delta[0], delta[1])
        self._turn_rad += abs(delta[2])

    def step(self, t_s: float, ends_sensor: np.ndarray) -> LocaliseStep:
        """The scan's end points (K, 2, laser frame) after the motion given to `predict`."""
        cfg = self.cfg
        due = self._travel_m >= cfg.update_travel_m or self._turn_rad >= cfg.update_turn_rad
        if not due or len(ends_sensor) < cfg.min_returns:
            pose, cov, share = self._estimate(self._anchor)
            if due:  # too few returns to tell where the robot is: on odometry alone, and not tracking
                self._last = LocaliseStep(t_s, pose, cov, len(self.poses), False, False, 0.0, share, 0,
                                          self._avg.fast, self._avg.slow)  # fmt: skip
            last = self._last
            return LocaliseStep(t_s, pose, cov, len(self.poses), False, last.tracking, last.fitness, share, 0,
                                self._avg.fast, self._avg.slow)  # fmt: skip
        moved = 0.0 if math.isinf(self._travel_m) else self._travel_m
        self._travel_m = self._turn_rad = 0.0
        self.updates += 1
        ends = np.asarray(ends_sensor, dtype=float)
        climb(self.model, self.poses, _subsample(ends, cfg.match_beams), cfg.match_step_xy_m, cfg.match_step_rad,
              cfg.match_levels)  # fmt: skip
        weigh = _subsample(ends, cfg.weight_beams)
        log_w, fit = log_likelihood(self.model, self.poses, weigh)
        log_w = np.log(self.weights) + log_w
        w = np.exp(log_w - log_w.max())
        w /= w.sum()
        # Augmented MCL: the likelihood per return (geometric mean) averaged over the particles.
        per_return = float(np.sum(self.weights * np.exp((log_w - np.log(self.weights)) / len(weigh))))
        avg = self._avg
        self.weights = w
        pose, cov, share = self._estimate()
        best = int(np.argmax(w))
        fitness = float(fit[best])
        tracking = self._tracking(cov, share, fitness)
        claimed = self._confirm(pose, moved, tracking)
        if not self._averaging:
            # The averages start at the first update that tracks: from a global start the first fits are
            # poor, and a long-term average begun there would take thousands of updates to learn what a
            # good fit is (until then w_fast stays above it and a kidnapping goes unnoticed).
            avg.slow = avg.fast = per_return
            self._averaging = tracking
        else:
            avg.slow += cfg.alpha_slow * (per_return - avg.slow)
            avg.fast += cfg.alpha_fast * (per_return - avg.fast)
        # Resampling: KLD-adaptive count, a share drawn afresh when the scan stops fitting.
        keep = kld_resample(self.poses, w, self.rng, cfg, cfg.max_particles)
        inject_p = max(0.0, 1.0 - avg.fast / avg.slow) if avg.slow > 0 else 0.0
        injected = int(self.rng.binomial(len(keep), inject_p)) if inject_p > 0 else 0
        poses = self.poses[keep]
        if injected:
            poses[self.rng.choice(len(keep), injected, replace=False)] = self.field.sample_free(injected, self.rng)
        if fitness < cfg.tracking_fitness and cfg.lost_particles:
            poses = np.vstack([poses, self.field.sample_free(cfg.lost_particles, self.rng)])
            injected += cfg.lost_particles
        self.poses = poses
        self.weights = np.full(len(poses), 1.0 / len(poses))
        self._anchor = self._nearest(pose)
        self._last = LocaliseStep(t_s, pose, cov, len(keep), True, claimed, fitness, share, injected,
                                  avg.fast, avg.slow)  # fmt: skip
        return self._last

    def _confirm(self, pose: np.ndarray, moved_m: float, tracking: bool) -> bool:
        """Whether to claim tracking at this update (`confirm_travel_m`): `tracking` (the tests of the update)
        on a hypothesis confirmed over enough travel. `moved_m`: odometry travel since the last update."""
        previous = self._hypothesis
        if previous is None or math.hypot(*(pose[:2] - previous[:2])) > moved_m + self.cfg.cluster_xy_m:
            self._confirmed_m = 0.0  # a jump: another place, to be confirmed afresh
        elif tracking:
            self._confirmed_m += moved_m
        self._hypothesis = pose.copy()
        return tracking and self._confirmed_m >= self.cfg.confirm_travel_m

    # ------------------------------------------------------------------------------------------
    def _nearest(self, pose: np.ndarray) -> int:
        d = self.poses - pose
        d[:, 2] = wrap_angle(d[:, 2])
        return int(np.argmin(d[:, 0] ** 2 + d[:, 1] ** 2 + d[:, 2] ** 2))

    def _estimate(self, centre: int | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(weighted mean pose of the main cluster, its covariance, the share of the weight it holds). The
        cluster is centred on particle `centre`: the heaviest at an update; after resampling, when the
        weights are all equal, the particle nearest the last estimate (`_anchor`)."""
        cfg = self.cfg
        best = self.poses[int(np.argmax(self.weights)) if centre is None else centre]
        d = self.poses - best
        d[:, 2] = wrap_angle(d[:, 2])
        near = (np.hypot(d[:, 0], d[:, 1]) <= cfg.cluster_xy_m) & (np.abs(d[:, 2]) <= cfg.cluster_rad)
        w = self.weights * near
        share = float(w.sum())
        w = w / share
        mean_d = w @ d
        pose = best + mean_d
        pose[2] = float(wrap_angle(pose[2]))
        e = d - mean_d
        cov = (e * w[:, None]).T @ e
        return pose, cov, share

    def _tracking(self, cov: np.ndarray, share: float, fitness: float) -> bool:
        cfg = self.cfg
        sd_xy = math.sqrt(max(0.0, float(np.linalg.eigvalsh(cov[:2, :2]).max())))
        sd_phi = math.sqrt(max(0.0, float(cov[2, 2])))
        return (
            share >= cfg.tracking_weight
            and sd_xy <= cfg.tracking_sigma_xy_m
            and sd_phi <= cfg.tracking_sigma_rad
            and fitness >= cfg.tracking_fitness
        )
