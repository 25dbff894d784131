"""Motion models, vectorised over particles: step 1 of the algorithm, s_t = f(s_{t-1}, u_t, eps) (eq. pose)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from gslam.vehicle import AckermannVehicle


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


_TWO_PI = 2.0 * math.pi


@njit(cache=True, inline="always")
def wrap_angle_scalar(a: float) -> float:  # pragma: no cover - compiled
    """`wrap_angle` of one angle, for compiled loops: (a + pi) % 2 pi - pi with Python's float modulo,
    bit for bit, without its call into numba's helper library where a + pi lies within 2 pi of [0, 2 pi)
    (always, for a sum or difference of two angles in [-pi, pi]): fmod is exact, and so are x - 2 pi for x in
    [2 pi, 4 pi) (Sterbenz) and the modulo's own x + 2 pi for x in (-2 pi, 0)."""
    x = a + math.pi
    if 0.0 <= x < _TWO_PI:
        pass
    elif _TWO_PI <= x < 2.0 * _TWO_PI:
        x = x - _TWO_PI
    elif -_TWO_PI < x < 0.0:
        x = x + _TWO_PI
    else:
        x = x % _TWO_PI
    return x - math.pi


def ackermann_step(
    poses: np.ndarray,
    speed_mps: np.ndarray | float,
    steering_rad: np.ndarray | float,
    dt_s: float,
    vehicle: AckermannVehicle,
) -> np.ndarray:
    """One Euler step of the paper's car model (eq. kinem) for the laser pose (x, y, phi).

    vc   = ve / (1 - tan(alpha) H / L)
    x   += dt (vc cos phi - vc/L tan(alpha) (a sin phi + b cos phi))
    y   += dt (vc sin phi + vc/L tan(alpha) (a cos phi - b sin phi))
    phi += dt vc/L tan(alpha)
    """
    L, H, a, b = vehicle.wheelbase_m, vehicle.encoder_offset_m, vehicle.laser_x_m, vehicle.laser_y_m
    x, y, phi = poses[..., 0], poses[..., 1], poses[..., 2]
    tan_s = np.tan(steering_rad)
    vc = speed_mps / (1.0 - tan_s * H / L)
    c, s = np.cos(phi), np.sin(phi)
    yaw_rate = vc / L * tan_s
    out = np.empty(np.broadcast_shapes(poses.shape, np.shape(vc) + (3,)))
    out[..., 0] = x + dt_s * (vc * c - yaw_rate * (a * s + b * c))
    out[..., 1] = y + dt_s * (vc * s + yaw_rate * (a * c - b * s))
    out[..., 2] = wrap_angle(phi + dt_s * yaw_rate)
    return out


def integrate_ackermann(
    poses: np.ndarray,
    controls: np.ndarray,
    t_end_s: float,
    t_start_s: float,
    vehicle: AckermannVehicle,
    rng: np.random.Generator | None = None,
    speed_sigma_mps: float = 0.0,
    speed_sigma_rel: float = 0.0,
    steering_sigma_rad: float = 0.0,
    per_sample: bool = False,
) -> np.ndarray:
    """Integrate every odometry sample between t_start_s and t_end_s (zero-order hold).

    controls: (K, 3) rows of t_s, speed_mps, steering_rad, where row 0 is the control in force at
    t_start_s (the last sample before it) and the others follow in time. Noise: speed gets
    N(0, speed_sigma_mps^2 + (speed_sigma_rel v)^2), steering N(0, steering_sigma_rad^2), drawn once per
    particle for the interval, or afresh per sample when per_sample.
    """
    poses = np.array(poses, dtype=float, copy=True)
    n = poses.shape[0]
    if len(controls) == 0:
        return poses
    controls = np.asarray(controls, dtype=float)
    # The intervals of the zero-order hold: sample k holds from max(t_k, t_start) to min(t_k+1, t_end).
    t0 = np.maximum(controls[:, 0], t_start_s)
    t1 = np.minimum(np.append(controls[1:, 0], t_end_s), t_end_s)
    dt = t1 - t0
    held = dt > 0
    dt, speed, steer = dt[held], controls[held, 1], controls[held, 2]
    k = len(dt)
    if k == 0:
        return poses
    noisy = rng is not None and (speed_sigma_mps > 0 or speed_sigma_rel > 0 or steering_sigma_rad > 0)
    v = np.repeat(speed[:, None], n, axis=1)
    s = np.repeat(steer[:, None], n, axis=1)
    if noisy:
        # Drawn in the order of a loop over the samples (speed, then steering, n each), or once.
        e = rng.standard_normal((k, 2, n)) if per_sample else np.broadcast_to(rng.standard_normal((2, n)), (k, 2, n))
        v = v + e[:, 0] * np.sqrt(speed_sigma_mps**2 + (speed_sigma_rel * v) ** 2)
        s = s + e[:, 1] * steering_sigma_rad
    L, H = vehicle.wheelbase_m, vehicle.encoder_offset_m
    _ackermann_chain(poses, dt, v, s, L, H, vehicle.laser_x_m, vehicle.laser_y_m)
    return poses


@njit(cache=True)
def _ackermann_chain(poses, dt, v, s, L, H, a, b):  # pragma: no cover - compiled
    """ackermann_step applied for every held sample k (rows of v, s) in turn, in place."""
    for k in range(dt.shape[0]):
        for i in range(poses.shape[0]):
            tan_s = math.tan(s[k, i])
            vc = v[k, i] / (1.0 - tan_s * H / L)
            phi = poses[i, 2]
            c, sn = math.cos(phi), math.sin(phi)
            yaw_rate = vc / L * tan_s
            poses[i, 0] += dt[k] * (vc * c - yaw_rate * (a * sn + b * c))
            poses[i, 1] += dt[k] * (vc * sn + yaw_rate * (a * c - b * sn))
            poses[i, 2] = wrap_angle_scalar(phi + dt[k] * yaw_rate)


def odometry_delta(prev: np.ndarray, cur: np.ndarray) -> tuple[float, float, float]:
    """(dx, dy, dtheta): the odometry's motion from `prev` to `cur` in the frame of `prev`."""
    dx, dy = cur[0] - prev[0], cur[1] - prev[1]
    c, s = np.cos(prev[2]), np.sin(prev[2])
    return float(c * dx + s * dy), float(-s * dx + c * dy), float(wrap_angle(cur[2] - prev[2]))


def apply_odometry(
    poses: np.ndarray,
    delta: tuple[float, float, float],
    rng: np.random.Generator | None,
    sigma: tuple[float, float, float, float],
) -> np.ndarray:
    """Sample the odometry motion model in the robot frame (GMapping's `MotionModel::drawFromMotion`).

    With the odometry's motion (dx, dy, dtheta) in the previous pose's frame and sigma = (srr, srt,
    str, stt), each particle moves by that motion plus Gaussian noise of standard deviation
        x:     srr |dx| + str |dtheta| + 0.3 srr |dy|
        y:     srr |dy| + str |dtheta| + 0.3 srr |dx|
        theta: stt |dtheta| + srt sqrt(dx^2 + dy^2)
    composed onto its own pose. Unlike the rot1-trans-rot2 model, turning on the spot with a few
    millimetres of wheel slip does not make the heading of the first rotation (and its noise) arbitrary.
    """
    dx, dy, dth = float(delta[0]), float(delta[1]), float(delta[2])
    poses = np.ascontiguousarray(poses, dtype=float)
    srr, srt, str_, stt = sigma
    out = np.empty_like(poses)
    if rng is not None:
        sxy = 0.3 * srr
        e = rng.standard_normal((poses.shape[0], 3))
        scale = (
            srr * abs(dx) + str_ * abs(dth) + sxy * abs(dy),
            srr * abs(dy) + str_ * abs(dth) + sxy * abs(dx),
            stt * abs(dth) + srt * float(np.hypot(dx, dy)),
        )
        _odometry_noisy(poses, dx, dy, dth, e, scale[0], scale[1], scale[2], out)
    else:
        _odometry_exact(poses, dx, dy, dth, out)
    return out


# The compiled loops of apply_odometry: once per scan and particle on odometry logs, where numpy's
# dozen small-array calls per scan cost more than the arithmetic. Same operations in the same order as
# the array expressions they replace (no contraction into fused multiply-adds), so the same results.


@njit(cache=True)
def _odometry_noisy(poses, dx, dy, dth, e, kx, ky, kth, out):  # pragma: no cover - compiled
    """out = poses moved by (dx + e0 kx, dy + e1 ky, dth + e2 kth) in each pose's own frame."""
    for i in range(poses.shape[0]):
        _compose(poses, i, dx + e[i, 0] * kx, dy + e[i, 1] * ky, dth + e[i, 2] * kth, out)


@njit(cache=True)
def _odometry_exact(poses, dx, dy, dth, out):  # pragma: no cover - compiled
    for i in range(poses.shape[0]):
        _compose(poses, i, dx, dy, dth, out)


@njit(cache=True, inline="always")
def _compose(poses, i, mx, my, mth, out):  # pragma: no cover - compiled
    c, s = math.cos(poses[i, 2]), math.sin(poses[i, 2])
    out[i, 0] = poses[i, 0] + c * mx - s * my
    out[i, 1] = poses[i, 1] + s * mx + c * my
    out[i, 2] = wrap_angle_scalar(poses[i, 2] + mth)
