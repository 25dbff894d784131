"""Simulated worlds with known truth for the tests: a car park of poles and walls driven round a loop,
and a corridor loop with pillars driven by an odometry robot with an offset laser."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from gslam.filter import GSlamFilter, StepResult
from gslam.motion import ackermann_step, apply_odometry, odometry_delta
from gslam.scan import Scan, ScanGeometry
from gslam.vehicle import AckermannVehicle
from pipelines.demo.world import World, ray_cast


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


def corridor_world(outer_m: float = 14.0, corridor_m: float = 2.0) -> World:
    """A square ring corridor `corridor_m` wide inside an `outer_m` square, with pillars and alcoves along
    the walls so that scan matching has features along the straight runs."""
    h, i = outer_m / 2, outer_m / 2 - corridor_m
    walls = [
        [-h, -h, h, -h],
        [h, -h, h, h],
        [h, h, -h, h],
        [-h, h, -h, -h],
        [-i, -i, i, -i],
        [i, -i, i, i],
        [i, i, -i, i],
        [-i, i, -i, -i],
    ]
    # Alcoves: boxes stuck on the outer walls (0.4 m deep), at irregular spacing.
    for x0, x1 in ((-4.0, -3.2), (1.5, 2.7)):
        walls += [[x0, -h + 0.4, x1, -h + 0.4], [x0, -h, x0, -h + 0.4], [x1, -h, x1, -h + 0.4]]
        walls += [[h - 0.4, x0, h - 0.4, x1], [h, x0, h - 0.4, x0], [h, x1, h - 0.4, x1]]
    walls += [[-2.0, h - 0.5, 0.5, h - 0.5], [-2.0, h, -2.0, h - 0.5], [0.5, h, 0.5, h - 0.5]]
    walls += [[-h + 0.3, 1.0, -h + 0.3, 3.0], [-h, 1.0, -h + 0.3, 1.0], [-h, 3.0, -h + 0.3, 3.0]]
    pillars = np.array([[-i - 0.25, -2.5, 0.15], [i + 0.25, 0.5, 0.15], [3.5, i + 0.25, 0.15], [-1.0, -i - 0.25, 0.15]])
    return World(pillars, np.array(walls, dtype=float))


def office_world() -> World:
    """A ring round an L-shaped block inside an uneven rectangle, with cabinets of different sizes along
    the outer walls and a few pillars: no two stretches of the ring look alike for long (the corridor world
    is a square whose quarter turns fit each other), for localisation's kidnap and recovery tests. The
    robot loop of `simulate_robot_loop` (half-side 6 m) runs clear of every wall."""
    walls = [
        [-8.5, -7.5, 8.0, -7.5],
        [8.0, -7.5, 8.0, 8.0],
        [8.0, 8.0, -8.5, 8.0],
        [-8.5, 8.0, -8.5, -7.5],
        # the block: a square with a notch cut from its top right corner
        [-4.5, -4.5, 4.5, -4.5],
        [4.5, -4.5, 4.5, 2.0],
        [4.5, 2.0, 3.0, 2.0],
        [3.0, 2.0, 3.0, 4.5],
        [3.0, 4.5, -4.5, 4.5],
        [-4.5, 4.5, -4.5, -4.5],
    ]
    for x0, y0, x1, y1 in ((-2.0, -7.5, 0.5, -6.8), (3.0, -7.5, 3.6, -7.0), (7.2, -3.0, 8.0, -1.0),
                           (7.4, 4.0, 8.0, 4.4), (-5.0, 7.0, -1.5, 8.0), (-8.5, -1.0, -7.1, 1.5)):  # fmt: skip
        walls += [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]
    pillars = np.array([[5.0, -5.2, 0.2], [-5.3, 5.4, 0.15], [-5.2, -5.0, 0.25]])
    return World(pillars, np.array(walls, dtype=float))


@dataclass
class RobotLog:
    """A robot's log: base poses (truth and odometry) and the scans of its mounted laser."""

    t_s: np.ndarray  # (T,) scan times
    truth: np.ndarray  # (T, 3) true base poses
    odometry: np.ndarray  # (T, 3) the base's odometry (drifts)
    ranges: np.ndarray  # (T, B) +inf where no return
    start_angle_rad: float
    angle_increment_rad: float
    max_range_m: float
    mount: np.ndarray  # (3,) the laser's pose on the base


def simulate_robot_loop(
    world: World,
    rng: np.random.Generator,
    mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
    centreline_m: float = 6.0,
    laps: float = 1.1,
    speed_mps: float = 0.8,
    scan_hz: float = 5.0,
    beam_count: int = 271,
    fov_rad: float = 1.5 * np.pi,
    max_range_m: float = 12.0,
    range_sigma_m: float = 0.01,
    odom_scale_error: float = 0.02,
    odom_yaw_drift_radpm: float = 0.01,
    odom_sigma_m: float = 0.005,
    odom_sigma_rad: float = 0.003,
) -> RobotLog:
    """Drive the robot counter-clockwise round the square of half-side `centreline_m` (corners rounded with
    a 1 m radius), scanning with a laser at `mount` on the base; the odometry has a scale error, a yaw
    drift per metre and noise per scan interval."""
    from gslam.motion import wrap_angle

    mount_pose = np.asarray(mount, dtype=float)
    c, r = centreline_m, 1.0
    side = 2 * (c - r)
    perimeter = 4 * side + 2 * np.pi * r
    n = int(laps * perimeter / speed_mps * scan_hz)
    s = (np.arange(n) * speed_mps / scan_hz + 0.5 * side) % perimeter  # start mid-way along the bottom side
    truth = np.empty((n, 3))
    seg = side + np.pi * r / 2  # one straight side and one corner
    corners = np.array([[c - r, -c + r], [c - r, c - r], [-c + r, c - r], [-c + r, -c + r]])
    starts = np.array([[-c + r, -c], [c, -c + r], [c - r, c], [-c, c - r]])
    for k, sk in enumerate(s):
        q, u = int(sk // seg), sk % seg
        heading0 = q * np.pi / 2
        if u < side:
            d = np.array([np.cos(heading0), np.sin(heading0)])
            truth[k] = [*(starts[q] + u * d), heading0]
        else:
            a = heading0 - np.pi / 2 + (u - side) / r
            truth[k] = [*(corners[q] + r * np.array([np.cos(a), np.sin(a)])), heading0 + (u - side) / r]
    truth[:, 2] = wrap_angle(truth[:, 2])
    odo = np.empty_like(truth)
    odo[0] = truth[0]
    for k in range(1, n):
        # The true motion in the previous base frame, distorted, applied to the odometry pose.
        c0, s0 = np.cos(truth[k - 1, 2]), np.sin(truth[k - 1, 2])
        dx, dy = truth[k, :2] - truth[k - 1, :2]
        fwd, left = c0 * dx + s0 * dy, -s0 * dx + c0 * dy
        dth = wrap_angle(truth[k, 2] - truth[k - 1, 2])
        dist = np.hypot(fwd, left)
        fwd = fwd * (1 + odom_scale_error) + rng.normal(0, odom_sigma_m)
        dth = dth + odom_yaw_drift_radpm * dist + rng.normal(0, odom_sigma_rad)
        co, so = np.cos(odo[k - 1, 2]), np.sin(odo[k - 1, 2])
        odo[k] = [odo[k - 1, 0] + co * fwd - so * left, odo[k - 1, 1] + so * fwd + co * left, odo[k - 1, 2] + dth]
    odo[:, 2] = wrap_angle(odo[:, 2])
    start = -fov_rad / 2
    inc = fov_rad / (beam_count - 1)
    bearings = start + inc * np.arange(beam_count)
    ranges = np.empty((n, beam_count))
    for k in range(n):  # one ray cast per scan, vectorised over beams
        ct, st = np.cos(truth[k, 2]), np.sin(truth[k, 2])
        lx = truth[k, 0] + ct * mount_pose[0] - st * mount_pose[1]
        ly = truth[k, 1] + st * mount_pose[0] + ct * mount_pose[1]
        rk = ray_cast(world, np.array([lx, ly]), truth[k, 2] + mount_pose[2] + bearings, max_range_m)
        ranges[k] = np.where(np.isfinite(rk), rk + rng.normal(0, range_sigma_m, beam_count), np.inf)
    return RobotLog(np.arange(n) / scan_hz, truth, odo, ranges, start, inc, max_range_m, mount_pose)


def drive_filter(
    flt: GSlamFilter, t_s: np.ndarray, odometry: np.ndarray, ranges: np.ndarray, geom: ScanGeometry
) -> Iterator[StepResult]:
    """Step `flt` through the scans (`ranges`, taken at `t_s`), moved between them by the odometry poses'
    differences with its own odometry noise; yields each step's result."""
    for k in range(len(ranges)):
        predict = None
        if k:
            delta = odometry_delta(odometry[k - 1], odometry[k])

            def predict(poses, rng, delta=delta):
                return apply_odometry(poses, delta, rng, flt.cfg.odom_sigma)

        yield flt.step(Scan(float(t_s[k]), ranges[k], geom), predict)
