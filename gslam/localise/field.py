"""The likelihood field of a fixed map: for every cell, the distance to the nearest obstacle, and where the
robot may stand (for a start with no initial pose and for recovery).

The scan matcher of SLAM (`gslam.scanmatch`) rasterises each particle's own map around each scan, because
the maps change at every update. A saved map does not change, so localisation computes the distances once
for the whole map (Thrun, Burgard & Fox 2005, the likelihood field model; AMCL's `map_update_cspace`), and
a return's likelihood is a lookup, interpolated bilinearly so that the climb of the scan-matching proposal
sees a smooth surface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage
from scipy.spatial import cKDTree

MAX_FIELD_CELLS = 100_000_000
"""The largest likelihood field built: as many cells as the largest occupancy grid gslam writes
(`pipelines.outputs.occupancy_grid.MAX_CELLS`), so every map `gslam export` writes can be localised in: a map
of 500 m x 500 m at 5 cm. Building one takes about 50 bytes a cell at its peak (scipy's distance transform
and the exact distances; 9 bytes a cell are kept), 5 GB at the cap; a larger map is refused before anything
is allocated, with its extent, rather than exhausting memory (two points 3 km apart on a diagonal make a
field of 1.8e9 cells)."""


def check_field_size(nx: float, ny: float, cell_m: float, what: str) -> None:
    """Refuse a field of `nx` x `ny` cells of `cell_m` over `MAX_FIELD_CELLS`; `what` says where its size
    comes from (the map's extent), for the message. Called before any array of that size exists; floats, so
    that an absurd extent is measured rather than overflowing."""
    cells = float(nx) * float(ny)
    if cells > MAX_FIELD_CELLS:
        raise ValueError(
            f"{what}: its likelihood field at {cell_m:g} m would be {nx:.6g} x {ny:.6g} = {cells:.3g} cells, over "
            f"the {MAX_FIELD_CELLS:.0e} that localisation builds (about {50 * MAX_FIELD_CELLS / 1e9:.0f} GB while "
            "it is built)"
        )


@dataclass(frozen=True)
class LikelihoodField:
    origin_xy_m: np.ndarray
    """(2,) world position of the corner of cell (0, 0)."""
    cell_m: float
    distance_m: np.ndarray
    """(ny, nx) float64: distance from each cell's centre to the nearest obstacle, capped at max_distance_m."""
    free: np.ndarray
    """(ny, nx) bool: cells the robot may stand in (known free space, clear of obstacles)."""
    max_distance_m: float

    @classmethod
    def from_grid(
        cls,
        occupied: np.ndarray,
        free: np.ndarray | None,
        origin_xy_m: np.ndarray,
        cell_m: float,
        max_distance_m: float = 2.0,
        clearance_m: float = 0.2,
    ) -> LikelihoodField:
        """From an occupancy grid (rows along y): `occupied` cells are obstacles; `free` cells (None: every
        cell) farther than `clearance_m` from an obstacle are where the robot may stand."""
        occupied = np.asarray(occupied, dtype=bool)
        ny, nx = occupied.shape
        check_field_size(nx, ny, cell_m, f"the map is {nx} x {ny} cells")
        if not occupied.any():
            raise ValueError("the map has no obstacles to localise against")
        dist = ndimage.distance_transform_edt(~occupied) * cell_m
        dist = np.minimum(dist, max_distance_m)
        standable = dist > clearance_m
        if free is not None:
            standable &= np.asarray(free, dtype=bool)
        if not standable.any():
            raise ValueError("the map has no free space clear of its obstacles")
        return cls(np.asarray(origin_xy_m, dtype=float), float(cell_m), dist.astype(np.float64), standable,
                   float(max_distance_m))  # fmt: skip

    @classmethod
    def from_points(
        cls,
        xy: np.ndarray,
        cell_m: float = 0.05,
        max_distance_m: float = 2.0,
        clearance_m: float = 0.2,
        reach_m: float = 3.0,
    ) -> LikelihoodField:
        """From obstacle points (K, 2), with no free space known: the robot may stand anywhere between
        `clearance_m` and `reach_m` from an obstacle (the band a laser sees walls from)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        if len(xy) == 0:
            raise ValueError("the map has no obstacles to localise against")
        bad = int((~np.isfinite(xy).all(axis=1)).sum())
        if bad:
            raise ValueError(f"{bad} of the map's {len(xy)} points are not finite numbers")
        margin = reach_m + cell_m
        lo = xy.min(axis=0) - margin
        span = xy.max(axis=0) - xy.min(axis=0)
        size = np.ceil((xy.max(axis=0) + margin - lo) / cell_m) + 1  # floats: an absurd extent does not overflow
        where = (  # the extent and the bounds: a few points far off (a bad result) show there
            f"the map spans {span[0]:.6g} m x {span[1]:.6g} m (x {xy[:, 0].min():.6g} to {xy[:, 0].max():.6g}, "
            f"y {xy[:, 1].min():.6g} to {xy[:, 1].max():.6g} m)"
        )
        check_field_size(size[0], size[1], cell_m, where)
        shape = size.astype(int)[::-1]
        occupied = np.zeros(shape, dtype=bool)
        ij = np.floor((xy - lo) / cell_m).astype(int)
        occupied[ij[:, 1], ij[:, 0]] = True
        field = cls.from_grid(occupied, None, lo, cell_m, max(max_distance_m, reach_m), clearance_m)
        near = field.distance_m <= reach_m
        # The exact distance from each cell's centre to the nearest point (the grid's is to the nearest
        # occupied cell's centre: up to half a cell off in each axis), where it matters: within reach.
        ny, nx = shape
        rows, cols = np.nonzero(field.distance_m < max_distance_m)
        centres = np.column_stack([lo[0] + (cols + 0.5) * cell_m, lo[1] + (rows + 0.5) * cell_m])
        exact = np.full(shape, float(max_distance_m))
        d, _ = cKDTree(xy).query(centres, distance_upper_bound=max_distance_m)
        exact[rows, cols] = np.minimum(d, max_distance_m)
        return cls(field.origin_xy_m, field.cell_m, exact, field.free & near, float(max_distance_m))

    @property
    def shape(self) -> tuple[int, int]:
        return self.distance_m.shape

    def distances(self, xy: np.ndarray) -> np.ndarray:
        """Interpolated distance to the nearest obstacle at world points (..., 2) (max_distance_m outside)."""
        xy = np.asarray(xy, dtype=float)
        flat = xy.reshape(-1, 2)
        out = np.empty(len(flat))
        _lookup(flat, self.origin_xy_m[0], self.origin_xy_m[1], self.cell_m, self.distance_m, self.max_distance_m, out)
        return out.reshape(xy.shape[:-1])

    def sample_free(self, count: int, rng: np.random.Generator) -> np.ndarray:
        """`count` poses (count, 3) uniform over the free cells (uniform within each) and in heading."""
        cells = np.flatnonzero(self.free.ravel())
        pick = cells[rng.integers(0, len(cells), count)]
        row, col = np.divmod(pick, self.shape[1])
        out = np.empty((count, 3))
        out[:, 0] = self.origin_xy_m[0] + (col + rng.random(count)) * self.cell_m
        out[:, 1] = self.origin_xy_m[1] + (row + rng.random(count)) * self.cell_m
        out[:, 2] = rng.uniform(-math.pi, math.pi, count)
        return out

    @property
    def free_area_m2(self) -> float:
        return float(self.free.sum()) * self.cell_m**2


@njit(cache=True, inline="always")
def value_at(x, y, x0, y0, cell_m, grid, outside):  # pragma: no cover - compiled
    """Bilinear interpolation of the cell-centre values `grid` at (x, y); `outside` beyond the grid."""
    gx = (x - x0) / cell_m - 0.5
    gy = (y - y0) / cell_m - 0.5
    ny, nx = grid.shape
    if not (0.0 <= gx < nx - 1 and 0.0 <= gy < ny - 1):
        return outside
    i, j = int(gx), int(gy)
    fx, fy = gx - i, gy - j
    v0 = grid[j, i] + fx * (grid[j, i + 1] - grid[j, i])
    v1 = grid[j + 1, i] + fx * (grid[j + 1, i + 1] - grid[j + 1, i])
    return v0 + fy * (v1 - v0)


@njit(cache=True)
def _lookup(xy, x0, y0, cell_m, dist, cap, out):  # pragma: no cover - compiled
    for k in range(xy.shape[0]):
        out[k] = value_at(xy[k, 0], xy[k, 1], x0, y0, cell_m, dist, cap)
