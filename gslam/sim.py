"""A small seeded simulator of a car-park-like world: round poles and walls, a SICK-like laser, the
Ackermann car of the Car Park preset, noisy odometry. Used by the tests as a world with known truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .motion import ackermann_step
from .vehicle import AckermannVehicle


@dataclass(frozen=True)
class World:
    """Poles: (P, 3) centre x, y and radius [m]. Walls: (W, 4) segments x0, y0, x1, y1 [m]."""

    poles: np.ndarray
    walls: np.ndarray


def ray_cast(world: World, origin: np.ndarray, angles_rad: np.ndarray, max_range_m: float) -> np.ndarray:
    """Range along each ray from `origin` (x, y) at world angles `angles_rad` to the nearest pole or wall
    (+inf when nothing lies within max_range_m). Vectorised over rays x obstacles."""
    d = np.column_stack([np.cos(angles_rad), np.sin(angles_rad)])  # (R, 2)
    best = np.full(len(angles_rad), np.inf)
    if len(world.poles):
        c = world.poles[:, :2] - origin  # (P, 2)
        b = d @ c.T  # (R, P): projection of centre on ray
        c2 = np.sum(c * c, axis=1)  # (P,)
        disc = b * b - (c2 - world.poles[:, 2] ** 2)
        t = b - np.sqrt(np.where(disc >= 0, disc, np.nan))
        t = np.where((disc >= 0) & (t > 0), t, np.inf)
        best = np.minimum(best, t.min(axis=1))
    if len(world.walls):
        p0 = world.walls[:, :2]
        e = world.walls[:, 2:] - p0  # (W, 2)
        w = p0 - origin  # (W, 2)
        den = d[:, 0:1] * e[None, :, 1] - d[:, 1:2] * e[None, :, 0]  # (R, W) = d x e
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / den
            s = (w[None, :, 0] * d[:, 1:2] - w[None, :, 1] * d[:, 0:1]) / den
        t = np.where((np.abs(den) > 1e-12) & (t > 0) & (s >= 0) & (s <= 1), t, np.inf)
        best = np.minimum(best, t.min(axis=1))
    return np.where(best <= max_range_m, best, np.inf)


def carpark_world(rng: np.random.Generator, size_m: float = 40.0, poles: int = 15) -> World:
    """A rectangular yard bounded by walls, with poles scattered in it (away from a central loop)."""
    h = size_m / 2
    walls = np.array(
        [
            [-h, -h, h, -h],
            [h, -h, h, h],
            [h, h, -h, h],
            [-h, h, -h, -h],
            [-h * 0.5, -h * 0.1, -h * 0.5 + 3, -h * 0.1],
            [h * 0.4, h * 0.2, h * 0.4, h * 0.2 + 4],
        ]
    )
    ang = rng.uniform(0, 2 * np.pi, poles)
    rad = rng.uniform(0.45 * h, 0.85 * h, poles)
    pts = np.column_stack([rad * np.cos(ang), rad * np.sin(ang), np.full(poles, 0.15)])
    return World(pts, walls)


@dataclass
class SimLog:
    truth: np.ndarray  # (T, 4) t, x, y, phi of the laser at scan times
    controls: np.ndarray  # (K, 3) t, measured speed, measured steering
    scan_t: np.ndarray
    ranges: np.ndarray  # (T, B)


def simulate_loop(
    world: World,
    vehicle: AckermannVehicle,
    rng: np.random.Generator,
    duration_s: float = 40.0,
    radius_m: float = 8.0,
    speed_mps: float = 2.0,
    odom_hz: float = 40.0,
    scan_hz: float = 4.7,
    beam_count: int = 361,
    max_range_m: float = 80.0,
    range_sigma_m: float = 0.02,
    speed_scale_error: float = 0.03,
    speed_sigma_mps: float = 0.05,
    steering_sigma_rad: float = 0.01,
) -> SimLog:
    """Drive a circle of `radius_m` at constant speed; record noisy odometry and laser scans."""
    steering = np.arctan(vehicle.wheelbase_m / radius_m)
    dt = 1.0 / odom_hz
    n = int(duration_s * odom_hz)
    pose = np.array([[0.0, -radius_m, 0.0]])
    scan_every = odom_hz / scan_hz
    bearings = np.linspace(-np.pi / 2, np.pi / 2, beam_count)
    truth, controls, scan_t, ranges = [], [], [], []
    next_scan = 0.0
    for k in range(n):
        t = k * dt
        controls.append(
            [
                t,
                speed_mps * (1 + speed_scale_error) + rng.normal(0, speed_sigma_mps),
                steering + rng.normal(0, steering_sigma_rad),
            ]
        )
        if k >= next_scan:
            r = ray_cast(world, pose[0, :2], pose[0, 2] + bearings, max_range_m)
            r = np.where(np.isfinite(r), r + rng.normal(0, range_sigma_m, len(r)), np.inf)
            truth.append([t, *pose[0]])
            scan_t.append(t)
            ranges.append(r)
            next_scan += scan_every
        pose = ackermann_step(pose, speed_mps, steering, dt, vehicle)
    return SimLog(np.array(truth), np.array(controls), np.array(scan_t), np.array(ranges))
