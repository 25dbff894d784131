"""Motion models, vectorised over particles: step 1 of the algorithm, s_t = f(s_{t-1}, u_t, eps) (eq. pose)."""

from __future__ import annotations

import numpy as np

from .vehicle import AckermannVehicle


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


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
    noisy = rng is not None and (speed_sigma_mps > 0 or speed_sigma_rel > 0 or steering_sigma_rad > 0)
    if noisy and not per_sample:
        e_v = rng.standard_normal(n)
        e_s = rng.standard_normal(n)
    for k in range(len(controls)):
        t0 = max(controls[k, 0], t_start_s)
        t1 = controls[k + 1, 0] if k + 1 < len(controls) else t_end_s
        t1 = min(t1, t_end_s)
        dt = t1 - t0
        if dt <= 0:
            continue
        v = np.full(n, controls[k, 1])
        s = np.full(n, controls[k, 2])
        if noisy:
            if per_sample:
                e_v = rng.standard_normal(n)
                e_s = rng.standard_normal(n)
            v = v + e_v * np.sqrt(speed_sigma_mps**2 + (speed_sigma_rel * v) ** 2)
            s = s + e_s * steering_sigma_rad
        poses = ackermann_step(poses, v, s, dt, vehicle)
    return poses


def odometry_delta(prev: np.ndarray, cur: np.ndarray) -> tuple[float, float, float]:
    """(rot1, trans, rot2) between two odometry poses (x, y, theta): the standard odometry model."""
    dx, dy = cur[0] - prev[0], cur[1] - prev[1]
    trans = float(np.hypot(dx, dy))
    rot1 = float(wrap_angle(np.arctan2(dy, dx) - prev[2])) if trans > 1e-6 else 0.0
    rot2 = float(wrap_angle(cur[2] - prev[2] - rot1))
    return rot1, trans, rot2


def apply_odometry(
    poses: np.ndarray,
    delta: tuple[float, float, float],
    rng: np.random.Generator | None,
    alpha: tuple[float, float, float, float],
) -> np.ndarray:
    """Sample the standard odometry motion model (Thrun et al., sample_motion_model_odometry)."""
    rot1, trans, rot2 = delta
    n = poses.shape[0]
    a1, a2, a3, a4 = alpha
    if rng is not None:
        # Backwards motion: treat rot1 near +-pi as reversing, as is common for wheeled robots.
        r1 = rot1 - rng.standard_normal(n) * np.sqrt(a1 * rot1**2 + a2 * trans**2)
        tr = trans - rng.standard_normal(n) * np.sqrt(a3 * trans**2 + a4 * (rot1**2 + rot2**2))
        r2 = rot2 - rng.standard_normal(n) * np.sqrt(a1 * rot2**2 + a2 * trans**2)
    else:
        r1, tr, r2 = np.full(n, rot1), np.full(n, trans), np.full(n, rot2)
    out = np.empty_like(poses)
    heading = poses[:, 2] + r1
    out[:, 0] = poses[:, 0] + tr * np.cos(heading)
    out[:, 1] = poses[:, 1] + tr * np.sin(heading)
    out[:, 2] = wrap_angle(poses[:, 2] + r1 + r2)
    return out
