"""Planar poses (x, y, heading) as rigid transforms: composition and inverse, vectorised over leading axes."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from gslam.motion import wrap_angle


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a (+) b: the pose b, given in the frame of pose a, in a's parent frame. Shapes (..., 3) broadcast."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            a[..., 0] + c * b[..., 0] - s * b[..., 1],
            a[..., 1] + s * b[..., 0] + c * b[..., 1],
            wrap_angle(a[..., 2] + b[..., 2]),
        ],
        axis=-1,
    )


def inverse(a: np.ndarray) -> np.ndarray:
    """a^-1, so that compose(a, inverse(a)) is the identity."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1], wrap_angle(-a[..., 2])],
        axis=-1,
    )


def interpolate(a: np.ndarray, b: np.ndarray, f: np.ndarray) -> np.ndarray:
    """The poses a fraction `f` (...,) of the way from `a` to `b` (..., 3): position along the straight line,
    heading along the shorter turn."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    f = np.asarray(f, dtype=float)
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., :2] = a[..., :2] + f[..., None] * (b[..., :2] - a[..., :2])
    out[..., 2] = wrap_angle(a[..., 2] + f * wrap_angle(b[..., 2] - a[..., 2]))
    return out


def compose_inverse(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """a (+) b^-1 for one pose each, in Python floats: `compose(a, inverse(b))` without numpy's per-call
    cost (a writer computes it at every scan: map -> odom is the SLAM pose (+) the odometry pose^-1)."""
    ca, sa = math.cos(a[2]), math.sin(a[2])
    cb, sb = math.cos(b[2]), math.sin(b[2])
    ix, iy = -cb * b[0] - sb * b[1], sb * b[0] - cb * b[1]
    phi = (a[2] - b[2] + math.pi) % (2 * math.pi) - math.pi
    return a[0] + ca * ix - sa * iy, a[1] + sa * ix + ca * iy, phi


def between_scalar(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """a^-1 (+) b for one pose each, in Python floats: the motion from a to b in a's frame; the heading
    change b - a is not wrapped (`compose_scalar` wraps the heading it gives)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return c * dx + s * dy, -s * dx + c * dy, b[2] - a[2]


def compose_scalar(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """a (+) b for one pose each, in Python floats (`compose` without numpy's per-call cost)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    phi = (a[2] + b[2] + math.pi) % (2 * math.pi) - math.pi
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], phi


between_compiled = njit(cache=True, inline="always")(between_scalar)
"""`between_scalar` for compiled loops (the same operations, so the same numbers)."""
compose_compiled = njit(cache=True, inline="always")(compose_scalar)
"""`compose_scalar` for compiled loops."""
