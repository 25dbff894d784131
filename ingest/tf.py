"""ROS transforms for ingest: 3-D rigid transforms, a frame tree built from /tf_static and /tf, and the
projection of the laser's mount onto the plane (x, y, yaw; or upside down).

A transform parent -> child maps child coordinates into the parent: p_parent = R p_child + t.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .textlog import IngestError

MAX_TILT_DEG = 10.0
"""A laser tilted more than this out of the horizontal plane (or out of upside down) is refused."""


def frame_name(frame_id: str) -> str:
    """ROS 1 frame ids may carry a leading slash ("/base_link"); tf2 drops it."""
    return frame_id.lstrip("/")


def quaternion_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if n < 1e-12 or not math.isfinite(n):
        raise ValueError("rotation quaternion has zero or non-finite length")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def yaw_of_quaternion(x: float, y: float, z: float, w: float) -> float:
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


@dataclass(frozen=True)
class Transform:
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)

    @classmethod
    def identity(cls) -> Transform:
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_ros(cls, transform) -> Transform:
        """From a geometry_msgs/msg/Transform (translation x, y, z; rotation x, y, z, w)."""
        t, q = transform.translation, transform.rotation
        return cls(quaternion_matrix(q.x, q.y, q.z, q.w), np.array([t.x, t.y, t.z], dtype=float))

    def then(self, child: Transform) -> Transform:
        """self (a -> b) composed with child (b -> c): the transform a -> c."""
        return Transform(self.rotation @ child.rotation, self.rotation @ child.translation + self.translation)


@dataclass(frozen=True)
class PlanarMount:
    """The laser's pose on the base, in the base's plane: x ahead, y left [m], yaw [rad] counter-clockwise.
    `upside_down`: the laser's z axis points down, so its beams sweep clockwise seen from above."""

    x_m: float
    y_m: float
    yaw_rad: float
    upside_down: bool = False


def planar_mount(t: Transform, what: str) -> PlanarMount:
    """Project a base -> laser transform onto the plane; a laser tilted out of it is refused."""
    z = float(np.clip(t.rotation[2, 2], -1.0, 1.0))
    tilt_deg = math.degrees(math.acos(abs(z)))
    if tilt_deg > MAX_TILT_DEG:
        raise IngestError(
            f"{what}: the laser is tilted {tilt_deg:.1f} deg out of the base's plane "
            f"(more than {MAX_TILT_DEG:.0f} deg); a 2-D laser SLAM needs a level laser"
        )
    yaw = math.atan2(t.rotation[1, 0], t.rotation[0, 0])
    return PlanarMount(float(t.translation[0]), float(t.translation[1]), yaw, upside_down=z < 0)


class FrameTree:
    """child -> (parent, transform) edges; later edges for the same child replace earlier ones."""

    def __init__(self) -> None:
        self.edges: dict[str, tuple[str, Transform]] = {}

    def add(self, parent: str, child: str, transform: Transform) -> None:
        self.edges[frame_name(child)] = (frame_name(parent), transform)

    def add_message(self, tf_message) -> None:
        """All transforms of a tf2_msgs/msg/TFMessage."""
        for ts in tf_message.transforms:
            self.add(ts.header.frame_id, ts.child_frame_id, Transform.from_ros(ts.transform))

    def path_up(self, frame: str) -> list[str]:
        """`frame`, its parent, grandparent, ... up to the root (cycles cut)."""
        path = [frame_name(frame)]
        while path[-1] in self.edges and len(path) <= len(self.edges):
            path.append(self.edges[path[-1]][0])
        return path

    def chain(self, ancestor: str, frame: str) -> Transform | None:
        """The transform ancestor -> frame along the tree, or None if `ancestor` is not above `frame`."""
        ancestor, frame = frame_name(ancestor), frame_name(frame)
        t = Transform.identity()
        node = frame
        for _ in range(len(self.edges) + 1):
            if node == ancestor:
                return t
            if node not in self.edges:
                return None
            parent, edge = self.edges[node]
            t = edge.then(t)
            node = parent
        return None

    def describe(self) -> str:
        if not self.edges:
            return "no transforms"
        return ", ".join(f"{p} -> {c}" for c, (p, _) in sorted(self.edges.items()))
