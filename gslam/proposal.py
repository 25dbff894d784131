"""Helpers of the scan-matching proposal (open point 6): the particles' maps laid out for the matcher.

The matcher itself is `gslam.fieldmatch` (GMapping's hill climbing on a raster of each particle's map
points near the scan).
"""

from __future__ import annotations

import numpy as np

from .pointmap import PointMap


def distinct_maps(maps: list[PointMap]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The distinct maps of the particles concatenated once: (xy (K, 2), p (K,), lo (N,), hi (N,)), where
    particle i's map is xy[lo[i]:hi[i]]. Particles that share a map after resampling share its range."""
    ids: dict[int, int] = {}
    distinct: list[PointMap] = []
    slot = np.empty(len(maps), dtype=np.int64)
    for i, m in enumerate(maps):
        k = ids.setdefault(id(m), len(distinct))
        if k == len(distinct):
            distinct.append(m)
        slot[i] = k
    sizes = np.array([len(m) for m in distinct], dtype=np.int64)
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    if bounds[-1] == 0:
        return np.empty((0, 2)), np.empty(0), bounds[slot], bounds[slot]
    xy = np.concatenate([m.xy for m in distinct])
    p = np.concatenate([m.p for m in distinct])
    return xy, p, bounds[slot], bounds[slot + 1]
