"""The probabilistic point map: points theta_k with probability p_k, one map per particle.

Each particle's map is an immutable `PointMap`; after resampling, particles share maps by reference
and each update writes new arrays (copy-on-write). `FlatMaps` concatenates all particles' maps with an
`owner` index, and `distinct_maps` lays the distinct maps out once for the compiled kernels. Steps 2
to 4, which change the maps, are in `gslam.mapupdate`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

MAP_DTYPE = np.float32
"""Storage of the map points and probabilities the compiled kernels read and write (computation is in
float64). float32 resolves a point to 1.2e-4 m at 1 km from the origin (the matcher's cells are 0.05 m)
and p to 6e-8, and halves the maps' memory, which on a long outdoor log is most of the filter's: the maps of all
particles, twice over while an update writes the new ones beside the old (docs/SPEED.md)."""
_CELL_BITS = 20  # per axis: |x| / cell_size < 2^19 (131 km at 0.25 m)
_OWNER_SHIFT = 2 * _CELL_BITS


def cell_keys(xy: np.ndarray, cell_size_m: float) -> np.ndarray:
    """Integer key of the grid cell of each point (the same grid for every particle and step)."""
    c = np.floor(xy / cell_size_m).astype(np.int64) + (1 << (_CELL_BITS - 1))
    return (c[:, 0] << _CELL_BITS) | c[:, 1]


def owner_cell_keys(owner: np.ndarray, xy: np.ndarray, cell_size_m: float) -> np.ndarray:
    """Keys ordered by particle, then cell: a map kept sorted by cell makes the concatenation sorted."""
    return (owner.astype(np.int64) << _OWNER_SHIFT) | cell_keys(xy, cell_size_m)


@dataclass(eq=False)
class PointMap:
    """Points (K, 2) and their probabilities (K,), sorted by grid cell (`cell_keys`). Arrays are
    read-only; the KD-tree (for the options that need one) is built lazily."""

    xy: np.ndarray
    p: np.ndarray
    _tree: cKDTree | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.xy.flags.writeable = False
        self.p.flags.writeable = False

    @classmethod
    def empty(cls) -> PointMap:
        return cls(np.empty((0, 2)), np.empty(0))

    def __len__(self) -> int:
        return len(self.p)

    @property
    def tree(self) -> cKDTree | None:
        if self._tree is None and len(self.p):
            from scipy.spatial import cKDTree  # imported here: only the KD-tree readings need it

            self._tree = cKDTree(self.xy)
        return self._tree

    @property
    def mean_p(self) -> float:
        return float(self.p.mean()) if len(self.p) else 1.0


@dataclass
class FlatMaps:
    """All particles' points concatenated: owner[k] is the particle of point k (sorted)."""

    xy: np.ndarray
    p: np.ndarray
    owner: np.ndarray

    @classmethod
    def of(cls, maps: list[PointMap]) -> FlatMaps:
        sizes = np.array([len(m) for m in maps])
        if sizes.sum() == 0:
            return cls(np.empty((0, 2)), np.empty(0), np.empty(0, dtype=np.int64))
        return cls(
            np.concatenate([m.xy for m in maps]),
            np.concatenate([m.p for m in maps]),
            np.repeat(np.arange(len(maps)), sizes),
        )

    def split(self, n: int) -> list[PointMap]:
        bounds = np.searchsorted(self.owner, np.arange(n + 1))
        return [PointMap(self.xy[a:b].copy(), self.p[a:b].copy()) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def segment_sum(values: np.ndarray, owner: np.ndarray, n: int) -> np.ndarray:
    return np.bincount(owner, weights=values, minlength=n)


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
