"""Every scan placed by the final map: the best particle's trajectory, each scan matched against its map.

The filter matches scans only at its updates (every `min_travel_m` or `min_turn_rad`); between updates a
particle's pose is its last update's pose moved by the odometry, so those scans carry the odometry's
error (its heading error above all) into the trajectory. And a matched pose at an update still carries
the proposal's sampling noise. Once the run is over, the best particle's map is the best knowledge of the
place, so each of its scans is matched against that map, from the pose the filter recorded for it, with
the update's matcher (`gslam.scanmatch.match_and_weigh`, one "particle"). The map is not changed.

A match is kept when enough of the scan's returns find the map near them (`min_hit_fraction`) and it moves
the pose by less than `max_shift_m` and `max_turn_rad` (more would be a jump to another part of the map,
not a correction). A scan whose match is not kept is placed between its matched neighbours: the recorded
path between them, corrected at each end to the matched poses, the correction blended by position along
it (`between_matched`). A scan with fewer than `min_returns` returns has nothing to match: it is placed
the same way and counted apart. When no scan at all is matched, the trajectory is left as recorded.

The map's points are sorted once into square tiles (`tile_m`) so that each match reads only the points
of the tiles its window covers, not the whole map.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from gslam.motion import wrap_angle
from gslam.scan import window_boxes
from gslam.scanmatch import MatchSettings, MatchWorkspace, match_and_weigh
from gslam.se2 import between_scalar, compose, compose_scalar, inverse

PLACED, BETWEEN, NO_RETURNS = 0, 1, 2
"""How a scan's pose was set: matched against the map; between matched neighbours (its match was not
kept); between matched neighbours for want of returns."""


@dataclass(frozen=True)
class PlacementLimits:
    """When a scan's match is kept."""

    min_returns: int = 10
    """Fewer returns than this: nothing to match (the scan is placed between matched neighbours)."""
    min_hit_fraction: float = 0.5
    """The share of the scan's returns that must find the map near their end points."""
    max_shift_m: float = 0.5
    """A match that moves the recorded pose further than this is a jump, not a correction."""
    max_turn_rad: float = 0.25
    """The same for the heading."""


@dataclass
class Placement:
    """The placed trajectory and how each scan got its pose (PLACED, BETWEEN, NO_RETURNS)."""

    poses: np.ndarray
    how: np.ndarray

    def counts(self) -> dict[str, int]:
        return {
            "scans": int(len(self.how)),
            "matched": int(np.sum(self.how == PLACED)),
            "between_matched": int(np.sum(self.how == BETWEEN)),
            "no_returns": int(np.sum(self.how == NO_RETURNS)),
        }


class MapTiles:
    """A point map's usable points (p >= min_p) sorted into square tiles, so that the points inside a box
    are found by one binary search per row of tiles."""

    def __init__(self, xy: np.ndarray, p: np.ndarray, min_p: float, tile_m: float = 4.0) -> None:
        keep = np.asarray(p) >= min_p
        xy = np.asarray(xy, dtype=float)[keep]
        p = np.asarray(p)[keep]
        self.tile_m = float(tile_m)
        self.origin = xy.min(axis=0) if len(xy) else np.zeros(2)
        cells = np.floor((xy - self.origin) / self.tile_m).astype(np.int64) if len(xy) else np.zeros((0, 2), np.int64)
        self.rows = int(cells[:, 1].max()) + 1 if len(cells) else 1
        self.cols = int(cells[:, 0].max()) + 1 if len(cells) else 1
        key = cells[:, 0] * self.rows + cells[:, 1]
        order = np.argsort(key, kind="stable")
        self.key = key[order]
        self.xy = np.ascontiguousarray(xy[order])
        self.p = np.ascontiguousarray(p[order])

    def inside(self, x0: float, y0: float, x1: float, y1: float) -> tuple[np.ndarray, np.ndarray]:
        """The points (and probabilities) of the tiles that the box [x0, x1] x [y0, y1] touches."""
        t = self.tile_m
        ix0 = max(0, int(math.floor((x0 - self.origin[0]) / t)))
        ix1 = min(self.cols - 1, int(math.floor((x1 - self.origin[0]) / t)))
        iy0 = max(0, int(math.floor((y0 - self.origin[1]) / t)))
        iy1 = min(self.rows - 1, int(math.floor((y1 - self.origin[1]) / t)))
        if ix1 < ix0 or iy1 < iy0:
            return self.xy[:0], self.p[:0]
        cols = np.arange(ix0, ix1 + 1, dtype=np.int64) * self.rows
        lo = np.searchsorted(self.key, cols + iy0, side="left")
        hi = np.searchsorted(self.key, cols + iy1, side="right")
        if len(lo) == 1:
            return self.xy[lo[0] : hi[0]], self.p[lo[0] : hi[0]]
        idx = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi, strict=True)])
        return self.xy[idx], self.p[idx]


ScanSource = Callable[[int, int], Iterable[tuple[np.ndarray, float]]]
"""scans(a, b): the scans a to b - 1 of the run, each as its returns' end points (K, 2) in the sensor frame
and the angle between its beams."""


def place_scans(
    map_xy: np.ndarray,
    map_p: np.ndarray,
    recorded: np.ndarray,
    scans: ScanSource,
    match: MatchSettings,
    limits: PlacementLimits = PlacementLimits(),
    anchored: np.ndarray | None = None,
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
    motion: np.ndarray | None = None,
) -> Placement:
    """Match each scan against the map (`map_xy`, `map_p`) and return the placed trajectory; the scans
    whose match is not kept are placed between matched neighbours. `scans(a, b)` gives the scans a to
    b - 1 in the order of `recorded` (T, 3, the poses the filter recorded); the angle between a scan's
    beams widens the score with range when match.score_sigma_rad is None, as in the filter.

    `anchored` (T,) bool: the scans whose recorded pose the filter matched (its updates); every other scan
    starts from the pose before it as placed, moved by the motion between the two (the
    odometry's error over one scan, not over everything since the last update). None: every scan starts
    from its recorded pose. `motion` (T, 3): the noise-free motion from each scan to the next (row k: from
    scan k - 1 to k, in the frame of k - 1), which the recorded poses break at the anchored scans (there
    the filter's correction is in them); None: the recorded poses' differences. `workers` > 1: the scans
    are cut at anchored scans into that many runs, placed at once (threads; the compiled matcher runs
    without the interpreter's lock), each reading its own scans: the same result as one worker.
    `progress(done, total)` is called every 256 scans or so."""
    recorded = np.asarray(recorded, dtype=float).reshape(-1, 3)
    n = len(recorded)
    path = recorded if motion is None else dead_reckoned(recorded[0], motion)
    poses = recorded.copy()
    how = np.full(n, BETWEEN, dtype=np.int8)
    tiles = MapTiles(map_xy, map_p, match.min_p)
    cuts = _cuts(n, anchored, workers)
    done = [0] * (len(cuts) - 1)
    lock = threading.Lock()

    def report(part: int, k: int) -> None:
        if progress is not None:
            with lock:
                done[part] = k
                progress(sum(done), n)

    def run(part: int) -> None:
        a, b = cuts[part], cuts[part + 1]
        _place_run(tiles, recorded, path, poses, how, a, b, scans(a, b), match, limits, anchored,
                   lambda k: report(part, k))  # fmt: skip

    if len(cuts) == 2:
        run(0)
    else:
        with ThreadPoolExecutor(len(cuts) - 1) as pool:
            for f in [pool.submit(run, part) for part in range(len(cuts) - 1)]:
                f.result()
    if progress is not None:
        progress(n, n)
    return Placement(between_matched(path, poses, how == PLACED), how)


def _cuts(n: int, anchored: np.ndarray | None, workers: int) -> list[int]:
    """Where the runs of `place_scans`'s workers begin (and n): at anchored scans (any scan when none are
    given) near equal shares of the scans; fewer runs when there are too few anchors."""
    cuts = [0]
    for j in range(1, max(1, int(workers))):
        target = n * j // workers
        if anchored is None:
            at = target
        else:
            after = np.flatnonzero(np.asarray(anchored[target:], dtype=bool))
            at = target + int(after[0]) if len(after) else n
        if cuts[-1] < at < n:
            cuts.append(at)
    return cuts + [n]


def _place_run(
    tiles: MapTiles,
    recorded: np.ndarray,
    path: np.ndarray,
    poses: np.ndarray,
    how: np.ndarray,
    a: int,
    b: int,
    scans: Iterable[tuple[np.ndarray, float]],
    match: MatchSettings,
    limits: PlacementLimits,
    anchored: np.ndarray | None,
    report: Callable[[int], None],
) -> None:
    """Place the scans a to b - 1 (`poses`, `how` written in place); scan a and the anchored ones start from
    their recorded pose, the others from the scan before as placed, moved as `path` moves."""
    workspace = MatchWorkspace(1)
    lo = np.zeros(1, dtype=np.int64)
    k = a - 1
    for k, (pts, increment_rad) in enumerate(scans, start=a):
        if k >= b:
            raise ValueError(f"more scans than recorded poses ({len(recorded)})")
        if (k - a) % 256 == 0:
            report(k - a)
        pts = np.asarray(pts, dtype=float).reshape(-1, 2)
        if anchored is None or anchored[k] or k == a:
            start = recorded[k : k + 1].copy()
        else:
            start = np.array([compose_scalar(poses[k - 1], between_scalar(path[k - 1], path[k]))])
        poses[k] = start[0]  # the next scan's start when this one is not matched
        if len(pts) < limits.min_returns:
            how[k] = NO_RETURNS
            continue
        x0, y0, x1, y1 = (float(v[0]) for v in window_boxes(start, pts, match.margin_m + limits.max_shift_m))
        xy, p = tiles.inside(x0, y0, x1, y1)
        if len(xy) == 0:
            continue
        matched, _, _, hits = match_and_weigh(
            xy, p, lo, np.array([len(xy)], dtype=np.int64), start, pts, workspace=workspace,
            **match.arguments(increment_rad),
        )  # fmt: skip
        q = matched[0]
        shift = math.hypot(q[0] - start[0, 0], q[1] - start[0, 1])
        turn = abs(float(wrap_angle(q[2] - start[0, 2])))
        explained = hits[0] >= limits.min_hit_fraction * len(pts)
        if explained and shift <= limits.max_shift_m and turn <= limits.max_turn_rad:
            poses[k] = q
            how[k] = PLACED
    if k + 1 != b:
        raise ValueError(f"{k + 1 - a} scans for the {b - a} recorded poses {a} to {b - 1}")


def dead_reckoned(start: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """The path (T, 3) from `start` moved by each row of `motion` (T, 3; row 0 ignored) in turn."""
    motion = np.asarray(motion, dtype=float).reshape(-1, 3)
    out = np.empty_like(motion)
    if len(out) == 0:
        return out
    pose = tuple(float(v) for v in start)
    out[0] = pose
    for k in range(1, len(motion)):
        pose = compose_scalar(pose, motion[k])
        out[k] = pose
    return out


def between_matched(recorded: np.ndarray, placed: np.ndarray, matched: np.ndarray) -> np.ndarray:
    """The poses of the scans not matched, placed between their matched neighbours a (before) and b
    (after): the motion of the path `recorded` (continuous: see `place_scans`'s `motion`) from a, laid from
    a's matched pose, and back from b, laid from b's matched pose, blended by the share of the path length
    from a to b (or of the scans, where it does not move); before the first matched scan only b's, after
    the last only a's. The matched scans keep `placed`; nothing matched: `recorded`."""
    recorded = np.asarray(recorded, dtype=float)
    out = np.asarray(placed, dtype=float).copy()
    idx = np.flatnonzero(matched)
    free = np.flatnonzero(~np.asarray(matched, dtype=bool))
    if len(idx) == 0:
        return recorded.copy()
    if len(free) == 0:
        return out
    steps = np.hypot(*np.diff(recorded[:, :2], axis=0).T)
    along = np.concatenate([[0.0], np.cumsum(steps)])
    after = np.searchsorted(idx, free)  # the matched neighbour after each free scan (len(idx): none)
    before = after - 1
    ia = idx[np.clip(before, 0, len(idx) - 1)]
    ib = idx[np.clip(after, 0, len(idx) - 1)]
    from_a = compose(out[ia], compose(inverse(recorded[ia]), recorded[free]))
    from_b = compose(out[ib], compose(inverse(recorded[ib]), recorded[free]))
    span = along[ib] - along[ia]
    scans = (ib - ia).astype(float)
    moved = span > 1e-9
    w = np.where(moved, (along[free] - along[ia]) / np.where(moved, span, 1.0), (free - ia) / np.maximum(scans, 1.0))
    w = np.where(before < 0, 1.0, np.where(after >= len(idx), 0.0, np.clip(w, 0.0, 1.0)))
    out[free, :2] = from_a[:, :2] + w[:, None] * (from_b[:, :2] - from_a[:, :2])
    out[free, 2] = wrap_angle(from_a[:, 2] + w * wrap_angle(from_b[:, 2] - from_a[:, 2]))
    return out
