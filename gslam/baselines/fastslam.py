"""FastSLAM 1.0 and 2.0 (Montemerlo et al. 2002, 2003): particles with per-landmark EKFs (baselines).

Observations are landmark (range, bearing) pairs, e.g. pole centres from `gslam.baselines.landmarks`. Data
association is maximum likelihood with a new-landmark threshold. The EKF maths per observation is
vectorised over a particle's landmarks; the loops run over particles and the few observations of a
scan (a handful of poles), never over map points.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gslam.ancestry import AncestryTree
from gslam.baselines.landmarks import PoleExtractorConfig, poles_from_geometry, poles_from_intensity
from gslam.filter import StepResult
from gslam.motion import wrap_angle
from gslam.resampling import continue_from_parents, reweight_and_resample
from gslam.scan import Scan


@dataclass(frozen=True)
class FastSlamConfig:
    particles: int = 8
    seed: int = 0
    version: int = 1
    """1: sample the motion model (FastSLAM 1.0); 2: sample a proposal that uses the observations."""
    range_sigma_m: float = 0.10
    bearing_sigma_rad: float = np.radians(1.0)
    new_landmark_likelihood: float = 1e-4
    """p0: an observation whose best association is less likely than this starts a new landmark."""
    resample_threshold: float = 0.5

    @property
    def R(self) -> np.ndarray:
        return np.diag([self.range_sigma_m**2, self.bearing_sigma_rad**2])


@dataclass(eq=False)
class LandmarkMap:
    """Landmark means (K, 2) and covariances (K, 2, 2); replaced, never modified (copy-on-write)."""

    mean: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    cov: np.ndarray = field(default_factory=lambda: np.empty((0, 2, 2)))

    def __len__(self) -> int:
        return len(self.mean)


def predict_observations(pose: np.ndarray, mean: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Expected (range, bearing) of landmarks (K, 2) from `pose`, their Jacobians with respect to the
    landmark (K, 2, 2) and with respect to the pose (K, 2, 3)."""
    d = mean - pose[:2]
    q = np.maximum(np.sum(d * d, axis=1), 1e-12)
    sq = np.sqrt(q)
    zhat = np.column_stack([sq, wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[2])])
    h_lm = np.stack([np.stack([d[:, 0] / sq, d[:, 1] / sq], 1), np.stack([-d[:, 1] / q, d[:, 0] / q], 1)], 1)
    h_pose = np.concatenate([-h_lm, np.stack([np.zeros(len(q)), -np.ones(len(q))], 1)[:, :, None]], axis=2)
    return zhat, h_lm, h_pose


def associate(pose: np.ndarray, lm: LandmarkMap, z: np.ndarray, R: np.ndarray):
    """Maximum-likelihood landmark for observation z: (index, likelihood, innovation, S, H) or None."""
    if len(lm) == 0:
        return None
    zhat, h, _ = predict_observations(pose, lm.mean)
    S = h @ lm.cov @ h.transpose(0, 2, 1) + R
    nu = z - zhat
    nu[:, 1] = wrap_angle(nu[:, 1])
    s_inv = np.linalg.inv(S)
    d2 = np.einsum("ki,kij,kj->k", nu, s_inv, nu)
    like = np.exp(-0.5 * d2) / (2 * np.pi * np.sqrt(np.linalg.det(S)))
    k = int(np.argmax(like))
    return k, float(like[k]), nu[k], S[k], h[k]


def ekf_update(mean: np.ndarray, cov: np.ndarray, nu: np.ndarray, S: np.ndarray, H: np.ndarray):
    """One landmark EKF update: K = P H^T S^-1, mean += K nu, P = (I - K H) P."""
    gain = cov @ H.T @ np.linalg.inv(S)
    new_cov = (np.eye(2) - gain @ H) @ cov
    return mean + gain @ nu, 0.5 * (new_cov + new_cov.T)


def new_landmark(pose: np.ndarray, z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Landmark from one observation: inverse of the measurement model, covariance G R G^T."""
    ang = pose[2] + z[1]
    mean = pose[:2] + z[0] * np.array([np.cos(ang), np.sin(ang)])
    G = np.array([[np.cos(ang), -z[0] * np.sin(ang)], [np.sin(ang), z[0] * np.cos(ang)]])
    return mean, G @ R @ G.T


class FastSlam:
    """FastSLAM 1.0 or 2.0 over landmark observations."""

    def __init__(self, cfg: FastSlamConfig, initial_pose: np.ndarray) -> None:
        self.cfg = cfg
        self.rng = np.random.default_rng(cfg.seed)
        self.poses = np.tile(np.asarray(initial_pose, float), (cfg.particles, 1))
        self.maps = [LandmarkMap()] * cfg.particles
        self.weights = np.full(cfg.particles, 1.0 / cfg.particles)
        self.tree = AncestryTree()
        self.resampled = False

    def step(self, t_s: float, observations: np.ndarray, predict, motion_cov: np.ndarray | None = None) -> float:
        """One step: observations (J, 2) of range and bearing; `predict(poses, rng)` samples the motion model
        (FastSLAM 1.0); FastSLAM 2.0 needs `motion_cov` (3x3), the pose covariance of one motion step, and
        samples each particle's pose from the Gaussian that includes the associated observations.
        Returns the effective sample size."""
        cfg, R = self.cfg, self.cfg.R
        if cfg.version == 1 or motion_cov is None:
            self.poses = predict(self.poses, self.rng)
        else:
            mean_poses = predict(self.poses, None)
            drawn = [self._proposal(i, mean_poses[i], observations, motion_cov) for i in range(cfg.particles)]
            self.poses = np.array([d[0] for d in drawn])
            proposal_log_w = np.array([d[1] for d in drawn])
        log_w = np.zeros(cfg.particles)
        for i in range(cfg.particles):  # per particle; the observations of a scan are few
            lm = self.maps[i]
            mean, cov = lm.mean, lm.cov
            for z in observations:
                found = associate(self.poses[i], LandmarkMap(mean, cov), z, R)
                if found is None or found[1] < cfg.new_landmark_likelihood:
                    m, c = new_landmark(self.poses[i], z, R)
                    mean, cov = np.vstack([mean, m]), np.concatenate([cov, c[None]])
                    log_w[i] += np.log(cfg.new_landmark_likelihood)
                else:
                    k, like, nu, S, H = found
                    m, c = ekf_update(mean[k], cov[k], nu, S, H)
                    mean, cov = mean.copy(), cov.copy()  # copy-on-write: other particles may share the map
                    mean[k], cov[k] = m, c
                    if cfg.version == 1 or motion_cov is None:
                        log_w[i] += np.log(like)
            if len(observations):
                self.maps[i] = LandmarkMap(mean, cov)
        if cfg.version == 2 and motion_cov is not None:
            log_w += proposal_log_w
        self.weights, ess, parents = reweight_and_resample(self.weights, log_w, cfg.resample_threshold, self.rng)
        self.tree.record(t_s, self.poses)
        self.resampled = parents is not None
        if self.resampled:
            self.poses, self.maps, self.weights = continue_from_parents(parents, self.poses, self.maps, self.tree)
        return ess

    def _proposal(
        self, i: int, pose: np.ndarray, observations: np.ndarray, motion_cov: np.ndarray
    ) -> tuple[np.ndarray, float]:
        """FastSLAM 2.0: refine the predicted pose with each associated observation in turn (Montemerlo
        2003: Sigma_s, mu_s) and sample from the result. Returns the sample and its log importance weight,
        the sum over associated observations of log N(nu; 0, Hs Sigma Hs^T + Q), each taken before that
        observation is fused."""
        mean, cov = pose.copy(), motion_cov.copy()
        log_w = 0.0
        lm = self.maps[i]
        for z in observations:
            found = associate(mean, lm, z, self.cfg.R)
            if found is None or found[1] < self.cfg.new_landmark_likelihood:
                continue
            k, _, nu, _, h_lm = found
            _, _, h_pose = predict_observations(mean, lm.mean[k : k + 1])
            hs = h_pose[0]
            Q = self.cfg.R + h_lm @ lm.cov[k] @ h_lm.T
            L = hs @ cov @ hs.T + Q
            log_w += float(-0.5 * nu @ np.linalg.solve(L, nu) - np.log(2 * np.pi * np.sqrt(np.linalg.det(L))))
            cov = np.linalg.inv(hs.T @ np.linalg.inv(Q) @ hs + np.linalg.inv(cov))
            mean = mean + cov @ hs.T @ np.linalg.inv(Q) @ nu
            mean[2] = wrap_angle(mean[2])
        sample = self.rng.multivariate_normal(mean, 0.5 * (cov + cov.T))
        sample[2] = wrap_angle(sample[2])
        return sample, log_w

    def best_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        return self.tree.trajectory(int(np.argmax(self.weights)))


class FastSlamFilter:
    """FastSLAM on pole observations extracted from laser scans: the pipeline's `SlamFilter` interface.

    Poles come from reflective returns when the scan has intensities, else from narrow foreground
    segments (`gslam.baselines.landmarks`). FastSLAM 2.0's motion covariance is estimated each step by sampling
    the motion model 64 times from the best pose (a separate seeded generator).
    """

    def __init__(
        self,
        cfg: FastSlamConfig,
        initial_pose: np.ndarray,
        min_range_m: float = 1.0,
        extractor: PoleExtractorConfig | None = None,
    ) -> None:
        self.cfg = cfg
        self.slam = FastSlam(cfg, initial_pose)
        self.min_range_m = min_range_m
        self.extractor = extractor or PoleExtractorConfig()
        self._cov_rng = np.random.default_rng(cfg.seed + 1_000_003)

    @property
    def poses(self) -> np.ndarray:
        return self.slam.poses

    @poses.setter
    def poses(self, value: np.ndarray) -> None:
        self.slam.poses = np.array(value, dtype=float)

    @property
    def weights(self) -> np.ndarray:
        return self.slam.weights

    @property
    def tree(self) -> AncestryTree:
        return self.slam.tree

    def best_particle(self) -> int:
        return int(np.argmax(self.slam.weights))

    def best_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        return self.slam.best_trajectory()

    def landmarks(self, particle: int) -> tuple[np.ndarray, np.ndarray]:
        """Landmark means (K, 2) and EKF covariances (K, 2, 2) of a particle."""
        lm = self.slam.maps[particle]
        return lm.mean, lm.cov

    def map_points(self, particle: int) -> tuple[np.ndarray, np.ndarray]:
        """Landmark means and, as "probability", a certainty 1 / (1 + trace(P) / trace(R_xy)) in (0, 1]."""
        lm = self.slam.maps[particle]
        scale = self.cfg.range_sigma_m**2 * 2
        return lm.mean, 1.0 / (1.0 + np.trace(lm.cov, axis1=1, axis2=2) / scale) if len(lm) else np.empty(0)

    def step(self, scan: Scan, predict=None, intensities: np.ndarray | None = None) -> StepResult:
        scan = Scan(scan.t_s, scan.ranges_m, scan.geometry, self.min_range_m)
        if intensities is not None and np.any(intensities > 0):
            r, b = poles_from_intensity(scan, intensities, self.extractor)
        else:
            r, b = poles_from_geometry(scan, self.extractor)
        obs = np.column_stack([r, b]) if len(r) else np.empty((0, 2))
        if predict is None:

            def predict(poses, rng):  # noqa: ARG001 - no motion
                return poses

        motion_cov = None
        if self.cfg.version == 2:
            best = self.slam.poses[self.best_particle()]
            samples = predict(np.tile(best, (64, 1)), self._cov_rng)
            d = samples - samples.mean(axis=0)
            d[:, 2] = wrap_angle(d[:, 2])
            motion_cov = d.T @ d / 63 + np.diag([1e-6, 1e-6, 1e-8])
        ess = self.slam.step(scan.t_s, obs, predict, motion_cov)
        best = self.best_particle()
        total = sum(len(m) for m in self.slam.maps)
        return StepResult(
            scan.t_s,
            self.slam.poses.copy(),
            self.slam.weights.copy(),
            ess,
            self.slam.resampled,
            True,
            best,
            self.slam.poses[best].copy(),
            len(self.slam.maps[best]),
            total,
            len(obs),
        )
