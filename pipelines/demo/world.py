"""The demo's world: a seeded car park (round poles with reflective tape, walls, parked cars) driven by
the Car Park vehicle with a SICK-like laser, written as a Sydney log with known truth (`gslam demo`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gslam.motion import ackermann_step
from gslam.vehicle import AckermannVehicle


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


# ---- a Sydney-style log: the Car Park vehicle driving a closed loop among poles, walls and parked cars --


@dataclass(frozen=True)
class SimConfig:
    """Simulated Car Park-like log. Defaults follow the real log's sensors and vehicle."""

    seed: int = 0
    size_m: float = 50.0
    poles: int = 15
    reflective_fraction: float = 0.6
    parked_cars: int = 8
    laps: float = 1.5
    speed_mps: float = 2.5
    max_steering_rad: float = 0.5
    odom_hz: float = 40.0
    scan_hz: float = 4.7
    gps_hz: float = 5.0
    beam_count: int = 361
    max_range_m: float = 80.0
    range_sigma_m: float = 0.03
    speed_scale_error: float = 0.04
    speed_sigma_mps: float = 0.05
    steering_sigma_rad: float = 0.005
    steering_bias_rad: float = 0.005
    gps_sigma_m: float = 0.05


def car_box(cx: float, cy: float, heading: float, length: float = 4.5, width: float = 1.8) -> np.ndarray:
    """The four sides of a parked car as wall segments (4, 4)."""
    c, s = np.cos(heading), np.sin(heading)
    hx, hy = length / 2, width / 2
    corners = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]]) @ np.array([[c, s], [-s, c]]) + [cx, cy]
    return np.hstack([corners, np.roll(corners, -1, axis=0)])


def demo_world(cfg: SimConfig, rng: np.random.Generator) -> tuple[World, np.ndarray, np.ndarray]:
    """(world, reflective flag per pole, loop waypoints (K, 2)). Obstacles stay clear of the loop."""
    h = cfg.size_m / 2
    loop = np.array([[-0.55 * h, -0.45 * h], [0.55 * h, -0.45 * h], [0.55 * h, 0.45 * h], [-0.55 * h, 0.45 * h]])
    walls = [np.array([[-h, -h, h, -h], [h, -h, h, h], [h, h, -h, h], [-h, h, -h, -h]])]
    # Parked cars in rows inside and outside the loop.
    spots = [(x, y) for x in np.linspace(-0.4 * h, 0.4 * h, 5) for y in (-0.15 * h, 0.15 * h, 0.75 * h, -0.75 * h)]
    for k in rng.choice(len(spots), size=min(cfg.parked_cars, len(spots)), replace=False):
        x, y = spots[k]
        walls.append(car_box(x + rng.normal(0, 0.3), y, np.pi / 2 + rng.normal(0, 0.05)))
    poles = []
    while len(poles) < cfg.poles:
        p = rng.uniform(-0.9 * h, 0.9 * h, 2)
        d_loop = np.min([_dist_to_segment(p, loop[i], loop[(i + 1) % 4]) for i in range(4)])
        if d_loop > 4.0 and all(np.hypot(*(p - q[:2])) > 3 for q in poles):
            poles.append([p[0], p[1], 0.1])
    reflective = rng.uniform(size=cfg.poles) < cfg.reflective_fraction
    return World(np.array(poles), np.vstack(walls)), reflective, loop


def _dist_to_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    e = b - a
    t = np.clip((p - a) @ e / (e @ e), 0, 1)
    return float(np.hypot(*(p - (a + t * e))))


@dataclass
class SydneyLog:
    """Arrays in the Sydney text-log layout plus the truth."""

    drs: np.ndarray  # t, measured rear-left wheel speed, measured steering
    gps: np.ndarray  # t, x, y
    laser: np.ndarray  # t, 361 ranges (81.91 = no return)
    intensity: np.ndarray  # t, 361 codes
    beacons: np.ndarray  # pole centres (all poles)
    truth: np.ndarray  # t, x, y, phi of the laser at scan times
    world: World
    reflective: np.ndarray


def simulate_sydney_log(cfg: SimConfig, vehicle: AckermannVehicle) -> SydneyLog:
    """Drive `cfg.laps` laps of a rounded rectangle with a pure-pursuit controller (steering limited),
    logging odometry (40 Hz, scale error, bias, noise), laser scans (361 beams, 0.5 deg, ~4.7 Hz,
    80 m, range noise, intensity on reflective poles) and GPS (5 Hz, noise)."""
    rng = np.random.default_rng(cfg.seed)
    world, reflective, loop = demo_world(cfg, rng)
    perimeter = float(sum(np.hypot(*(loop[(i + 1) % 4] - loop[i])) for i in range(4)))
    duration = cfg.laps * perimeter / cfg.speed_mps
    dt = 1.0 / cfg.odom_hz
    L, H = vehicle.wheelbase_m, vehicle.encoder_offset_m
    # Start on the bottom side, heading along it.
    pose = np.array([[loop[0, 0] + 5.0, loop[0, 1], 0.0]])
    bearings = np.linspace(-np.pi / 2, np.pi / 2, cfg.beam_count)
    drs, gps, laser, inten, truth = [], [], [], [], []
    next_scan, next_gps = 0.0, 0.0
    t0 = 45.0  # the real log's clock starts near 45 s
    for k in range(int(duration * cfg.odom_hz)):
        t = k * dt
        steer = np.clip(
            _pure_pursuit(pose[0], loop, vehicle, lookahead=6.0), -cfg.max_steering_rad, cfg.max_steering_rad
        )
        vc = cfg.speed_mps
        ve = vc * (1 - np.tan(steer) * H / L)
        drs.append(
            [
                t0 + t,
                ve * (1 + cfg.speed_scale_error) + rng.normal(0, cfg.speed_sigma_mps),
                steer + cfg.steering_bias_rad + rng.normal(0, cfg.steering_sigma_rad),
            ]
        )
        if t >= next_gps:
            gps.append([t0 + t, *(pose[0, :2] + rng.normal(0, cfg.gps_sigma_m, 2))])
            next_gps += 1.0 / cfg.gps_hz
        if t >= next_scan:
            r, hit_pole = _scan_with_hits(world, pose[0], bearings, cfg.max_range_m)
            noisy = np.where(np.isfinite(r), r + rng.normal(0, cfg.range_sigma_m, len(r)), 81.91)
            code = np.where((hit_pole >= 0) & reflective[np.maximum(hit_pole, 0)], 8192 * rng.integers(1, 5, len(r)), 0)
            laser.append([t0 + t, *np.round(noisy, 2)])
            inten.append([t0 + t, *code])
            truth.append([t0 + t, *pose[0]])
            next_scan += 1.0 / cfg.scan_hz
        pose = ackermann_step(pose, ve, steer, dt, vehicle)
    return SydneyLog(
        np.array(drs),
        np.array(gps),
        np.array(laser),
        np.array(inten),
        world.poles[:, :2],
        np.array(truth),
        world,
        reflective,
    )


def _pure_pursuit(pose: np.ndarray, loop: np.ndarray, vehicle: AckermannVehicle, lookahead: float) -> float:
    """Steering towards the point `lookahead` metres ahead on the loop (counter-clockwise)."""
    pts = _densify(loop)
    i = int(np.argmin(np.hypot(pts[:, 0] - pose[0], pts[:, 1] - pose[1])))
    target = pts[(i + int(lookahead / 0.5)) % len(pts)]
    ang = np.arctan2(target[1] - pose[1], target[0] - pose[0]) - pose[2]
    ang = (ang + np.pi) % (2 * np.pi) - np.pi
    return float(np.arctan2(2 * vehicle.wheelbase_m * np.sin(ang), lookahead))


_DENSE: dict[bytes, np.ndarray] = {}


def _densify(loop: np.ndarray, step: float = 0.5) -> np.ndarray:
    key = loop.tobytes()
    if key not in _DENSE:
        pts = []
        for i in range(len(loop)):
            a, b = loop[i], loop[(i + 1) % len(loop)]
            n = max(int(np.hypot(*(b - a)) / step), 1)
            pts.append(a + (b - a) * np.arange(n)[:, None] / n)
        _DENSE[key] = np.vstack(pts)
    return _DENSE[key]


def _scan_with_hits(world: World, pose: np.ndarray, bearings: np.ndarray, max_range_m: float):
    """Ranges and, per ray, the index of the pole it hit (-1: a wall or nothing)."""
    angles = pose[2] + bearings
    r_all = ray_cast(world, pose[:2], angles, max_range_m)
    r_walls = ray_cast(World(np.empty((0, 3)), world.walls), pose[:2], angles, max_range_m)
    hit_pole = np.full(len(bearings), -1)
    pole_hit = np.isfinite(r_all) & (r_all < r_walls - 1e-9)
    if pole_hit.any():
        ends = pose[:2] + r_all[pole_hit, None] * np.column_stack([np.cos(angles[pole_hit]), np.sin(angles[pole_hit])])
        d = np.hypot(ends[:, None, 0] - world.poles[None, :, 0], ends[:, None, 1] - world.poles[None, :, 1])
        hit_pole[pole_hit] = np.argmin(d, axis=1)
    return r_all, hit_pole


def distance_to_obstacles(world: World, xy: np.ndarray) -> np.ndarray:
    """Distance from each point (K, 2) to the nearest obstacle surface (pole rim or wall segment)."""
    d = np.full(len(xy), np.inf)
    for cx, cy, r in world.poles:
        d = np.minimum(d, np.abs(np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) - r))
    for x0, y0, x1, y1 in world.walls:
        e = np.array([x1 - x0, y1 - y0])
        t = np.clip(((xy[:, 0] - x0) * e[0] + (xy[:, 1] - y0) * e[1]) / (e @ e), 0, 1)
        d = np.minimum(d, np.hypot(xy[:, 0] - (x0 + t * e[0]), xy[:, 1] - (y0 + t * e[1])))
    return d


# ---- an indoor robot: a differential-drive base with a laser mounted on it, in a ring corridor ------
