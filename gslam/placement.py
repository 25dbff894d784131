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

An update's scan starts from the pose the filter recorded there, the scans after it from the one before
as placed. Where the pose tracked to the update's scan (the scan before moved by the motion) differs from
the recorded one, that scan and the rest of its segment (up to the next update) are placed from both, and
the chain that fits the map better is kept (`Retrack`): a jump the filter took at an update is undone when
the scans after it do not bear it out.

The map's points are sorted once into square tiles (`tile_m`) so that a raster reads only the points of
the tiles it covers, not the whole map. The map is rasterised more than once (`rasters`), each raster's
cell lattice shifted over the cell (`raster_shifts`): a scan is climbed on the first and finished by
Gauss-Newton on the others, and placed at the mean, so that where the cell edges fall matters less. A
raster reaches beyond the window that asked for it and is kept while the next scans' windows lie inside
it. The scans are placed in batches by one compiled call each (`_place_batch`, the matcher's own
kernels), so no scan costs an interpreter round trip.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numba import njit

from gslam.motion import wrap_angle_scalar
from gslam.pointmap import MAP_DTYPE
from gslam.scan import end_point_box
from gslam.scanmatch import _EMPTY, MatchSettings, _fine_climb, _finish, _rasterise_range, _to_means
from gslam.se2 import between_compiled, compose, compose_compiled, compose_scalar, interpolate, inverse

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


@dataclass(frozen=True)
class Retrack:
    """An update's scan placed a second time, from the pose tracked to it: the scan before as the first pass
    placed it, moved by the motion between the two. The first pass starts it from the pose the filter
    recorded there, which carries the update's correction, right or wrong: along a corridor a particle
    filter can take a jump that one scan's returns favour and the next ones' do not. Where the tracked
    start lies at least `gate_m` or `gate_rad` from the recorded one, the scan and those after it up to the
    next update (its segment) are placed on from the tracked start too, and the new chain is kept when both
    the scans and the motion favour it: its matches score higher over the segment (the sum of each scan's
    score per return, 0 for a match not kept), and its steps, from the scan before to the next update's
    recorded pose, stray less from the motion (`off_motion`). The scans alone would decide by chance where
    they cannot tell poses apart (a featureless corridor), and a chain kept there slides along it."""

    gate_m: float = 0.02
    gate_rad: float = 0.01

    def start(self, before: np.ndarray, path: np.ndarray, recorded: np.ndarray, k: int) -> np.ndarray | None:
        """The tracked start of anchored scan k (`before`, the first pass's pose of scan k - 1, moved as `path`
        moves), or None where it lies too near the recorded one to place the segment again."""
        tracked = compose(before, compose(inverse(path[k - 1]), path[k]))
        d = compose(inverse(tracked), recorded[k])
        return tracked if math.hypot(d[0], d[1]) >= self.gate_m or abs(d[2]) >= self.gate_rad else None


def _segment_end(anchor: np.ndarray, k: int, stop: int) -> int:
    """The next anchored scan after k, or `stop` if none comes before it: anchored scan k's segment is k to
    that scan - 1."""
    e = k + 1
    while e < stop and not anchor[e]:
        e += 1
    return e


@dataclass
class Placement:
    """The placed trajectory and how each scan got its pose (PLACED, BETWEEN, NO_RETURNS)."""

    poses: np.ndarray
    how: np.ndarray
    retracked: int = 0
    """The update segments whose chain from the tracked start was kept (`Retrack`)."""

    def counts(self) -> dict[str, int]:
        return {
            "scans": int(len(self.how)),
            "matched": int(np.sum(self.how == PLACED)),
            "between_matched": int(np.sum(self.how == BETWEEN)),
            "no_returns": int(np.sum(self.how == NO_RETURNS)),
            "retracked_segments": int(self.retracked),
        }


class MapTiles:
    """A point map's usable points (p >= min_p) sorted into square tiles, so that the points inside a box
    are found by one binary search per column of tiles (`_tile_ranges`)."""

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
        # in the matcher's precision once, not converted at every match
        self.xy = np.ascontiguousarray(xy[order], dtype=MAP_DTYPE)
        self.p = np.ascontiguousarray(p[order], dtype=MAP_DTYPE)


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
    times: np.ndarray | None = None,
    search: MatchSettings | None = None,
    rasters: int = 1,
    retrack: Retrack | None = None,
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
    `progress(done, total)` is called every 256 scans or so. `rasters`: how many rasters of the map, their
    lattices shifted over the cell, a scan's match is the mean of (`_place_batch`). `retrack`: each anchored
    scan's segment placed again from the pose tracked to it where that differs (`Retrack`); None: off.

    A scan whose match is not kept, or whose motion breaks from its neighbours', is matched once more from
    the pose between the matched scans around it, interpolated by its time (`times`, T; None: by its
    index), and from that heading and position mixed with the two scans' own (`_second_starts`), with the
    `search` matcher (None: `match`; the filter passes the update's), and the best of its matches kept:
    the start from the scan before fails where the motion does (an odometry reading lost for one scan,
    then caught up at the next), and along a corridor or a road such a wrong start can still match."""
    recorded = np.asarray(recorded, dtype=float).reshape(-1, 3)
    n = len(recorded)
    path = recorded if motion is None else dead_reckoned(recorded[0], motion)
    poses = recorded.copy()
    how = np.full(n, BETWEEN, dtype=np.int8)
    tiles = MapTiles(map_xy, map_p, match.min_p)
    cuts = _cuts(n, anchored, workers)
    done = [0] * (len(cuts) - 1)
    lock = threading.Lock()
    unplaced: dict[int, tuple[np.ndarray, float]] = {}  # the scans not placed, for the second start
    suspect = _motion_breaks(path, anchored)
    fit = np.zeros(n)

    def report(part: int, k: int) -> None:
        if progress is not None:
            with lock:
                done[part] = k
                progress(sum(done), n)

    run_ends = [(np.zeros(3), 0)] * (len(cuts) - 1)  # the first pass's pose of each run's last scan, retracks

    def run(part: int) -> None:
        a, b = cuts[part], cuts[part + 1]
        run_ends[part] = _place_run(tiles, recorded, path, poses, how, a, b, scans(a, b), match, limits, anchored,
                                    lambda k: report(part, k), fit, unplaced, suspect, rasters, retrack)  # fmt: skip

    if len(cuts) == 2:
        run(0)
    else:
        with ThreadPoolExecutor(len(cuts) - 1) as pool:
            for f in [pool.submit(run, part) for part in range(len(cuts) - 1)]:
                f.result()
    retracked = sum(kept for _, kept in run_ends)
    if retrack is not None and anchored is not None:
        anchor = np.asarray(anchored, dtype=bool)
        for part in range(1, len(cuts) - 1):  # where a run began, the scan before was another's
            k = cuts[part]
            e = _segment_end(anchor, k, n)
            before = run_ends[part - 1][0]
            tracked = retrack.start(before, path, recorded, k)
            if tracked is not None:
                retracked += _retrack_segment(tiles, recorded, path, poses, how, fit, k, e, before, tracked,
                                              scans(k, e), match, limits, anchored, unplaced, suspect,
                                              rasters)  # fmt: skip
    _place_again_between(
        tiles, poses, how, fit, unplaced, suspect, match if search is None else search, limits, times, rasters
    )
    if progress is not None:
        progress(n, n)
    return Placement(between_matched(path, poses, how == PLACED), how, retracked)


def _retrack_segment(
    tiles: MapTiles,
    recorded: np.ndarray,
    path: np.ndarray,
    poses: np.ndarray,
    how: np.ndarray,
    fit: np.ndarray,
    k: int,
    e: int,
    before: np.ndarray,
    tracked: np.ndarray,
    returns: Iterable[tuple[np.ndarray, float]],
    match: MatchSettings,
    limits: PlacementLimits,
    anchored: np.ndarray,
    unplaced: dict[int, tuple[np.ndarray, float]],
    suspect: np.ndarray,
    rasters: int,
) -> bool:
    """`Retrack` for the segment k to e - 1 that begins a worker's run (`place_scans`): placed again from
    `tracked` (`before`, the first pass's pose of scan k - 1, moved by the motion), as `_place_run` does
    within a run; the new chain kept as `_keeps` decides, its scans' returns kept in `unplaced` as the
    chain's own run would have kept them. Returns whether the new chain was kept."""
    rec = recorded.copy()
    rec[k] = tracked
    alt_poses, alt_how, alt_fit = poses.copy(), np.full_like(how, BETWEEN), np.zeros_like(fit)
    alt_unplaced: dict[int, tuple[np.ndarray, float]] = {}
    _place_run(tiles, rec, path, alt_poses, alt_how, k, e, returns, match, limits, anchored, lambda j: None,
               alt_fit, alt_unplaced, suspect, rasters)  # fmt: skip
    if _keeps(before, path, recorded, k, e, (poses, fit), (alt_poses, alt_fit)):
        poses[k:e], how[k:e], fit[k:e] = alt_poses[k:e], alt_how[k:e], alt_fit[k:e]
        for j in range(k, e):
            unplaced.pop(j, None)
        unplaced.update(alt_unplaced)
        return True
    return False


def off_motion(before: np.ndarray, chain: np.ndarray, path: np.ndarray, k: int, end: np.ndarray | None) -> float:
    """How far a chain of poses (the scans k, k + 1, ..., `chain` (M, 3)) strays from the motion of `path`:
    the sum over its steps, from the pose `before` of scan k - 1 through the chain to `end` (the next
    scan's pose, None: none), of the step's difference from the path's step (its length in m plus its
    turn in rad)."""
    poses = np.vstack([before[None], chain] + ([end[None]] if end is not None else []))
    last = k + len(poses) - 1
    steps = compose(inverse(poses[:-1]), poses[1:])
    moved = compose(inverse(path[k - 1 : last - 1]), path[k:last])
    d = compose(inverse(moved), steps)
    return float(np.sum(np.hypot(d[:, 0], d[:, 1]) + np.abs(d[:, 2])))


def _keeps(
    before: np.ndarray, path: np.ndarray, recorded: np.ndarray, k: int, e: int, first: tuple, again: tuple
) -> bool:
    """`Retrack`'s choice for the segment k to e - 1: whether the chain `again` (poses, fits) beats `first`,
    in score and in keeping to the motion (to the next update's recorded pose, when there is one)."""
    if again[1][k:e].sum() <= first[1][k:e].sum():
        return False
    end = recorded[e] if e < len(recorded) else None
    return off_motion(before, again[0][k:e], path, k, end) < off_motion(before, first[0][k:e], path, k, end)


SUSPECT_SHIFT_M = 0.25
SUSPECT_TURN_RAD = 0.1
"""A scan's motion breaks from its neighbours' when it differs from their mean by this much."""


def raster_shifts(rasters: int, cell_m: float) -> np.ndarray:
    """The shifts (rasters, 2) of the placement's rasters' cell lattices from the map frame's, in m: the
    Hammersley points (j / rasters, the bits of j mirrored about the binary point) of the unit square,
    moved half their spacing off the origin, times the cell. Spread evenly over the cell, so that their
    cell edges fall at different places in both directions, and none on the map frame's lattice (a raster
    on it placed intel's scans worse: docs/CHOICES.md)."""
    j = np.arange(rasters)
    mirrored = np.zeros(rasters)
    bit, rest = 0.5, j.copy()
    while rest.any():
        mirrored += bit * (rest & 1)
        rest >>= 1
        bit *= 0.5
    return np.column_stack([(j + 0.5) / rasters, (mirrored + 0.5 / rasters) % 1.0]) * cell_m


def _motion_breaks(path: np.ndarray, anchored: np.ndarray | None) -> np.ndarray:
    """The scans (T,) bool, not anchored, whose motion from the scan before differs from the mean of the
    motions before and after it by SUSPECT_SHIFT_M or SUSPECT_TURN_RAD: an odometry reading lost for one
    scan (no motion, then twice the motion), or a spike."""
    n = len(path)
    out = np.zeros(n, dtype=bool)
    if n < 3:
        return out
    step = compose(inverse(path[:-1]), path[1:])  # row k: the motion into scan k + 1
    mean = 0.5 * (step[:-1] + step[1:])
    diff = step[:-1] - mean  # scan k + 1's motion against the mean of its own and the next one's
    out[1:-1] = (np.hypot(diff[:, 0], diff[:, 1]) >= SUSPECT_SHIFT_M) | (np.abs(diff[:, 2]) >= SUSPECT_TURN_RAD)
    if anchored is not None:
        out &= ~np.asarray(anchored, dtype=bool)
    return out


def _place_again_between(
    tiles: MapTiles,
    poses: np.ndarray,
    how: np.ndarray,
    fit: np.ndarray,
    unplaced: dict[int, tuple[np.ndarray, float]],
    suspect: np.ndarray,
    match: MatchSettings,
    limits: PlacementLimits,
    times: np.ndarray | None,
    rasters: int = 1,
) -> None:
    """The second start of `place_scans`, for the scans not placed and those whose motion breaks from their
    neighbours' (`_motion_breaks`; returns in `unplaced`): each matched from the pose interpolated by time
    between the placed scans around it, and kept where its match is kept and fits better
    than the first one's. `poses`, `how` and `fit` written in place."""
    placed = np.flatnonzero(how == PLACED)
    if len(placed) < 2 or not unplaced:
        return
    at = np.array(sorted(k for k in unplaced if how[k] != NO_RETURNS), dtype=np.int64)
    before = np.searchsorted(placed, at, side="left") - 1  # the placed scans around each, not itself
    after = np.searchsorted(placed, at, side="right")
    inside = (before >= 0) & (after < len(placed))
    at, before, after = at[inside], before[inside], after[inside]
    if len(at) == 0:
        return
    ia, ib = placed[before], placed[after]
    clock = np.arange(len(poses), dtype=float) if times is None else np.asarray(times, dtype=float)
    span = clock[ib] - clock[ia]
    f = np.where(span > 0, (clock[at] - clock[ia]) / np.where(span > 0, span, 1.0), (at - ia) / (ib - ia))
    f = np.clip(f, 0.0, 1.0)
    between = interpolate(poses[ia], poses[ib], f)
    returns = [unplaced[int(k)] for k in at]
    for start in _second_starts(between, poses[ia], poses[ib]):
        again = start.copy()
        how_again = np.full(len(at), BETWEEN, dtype=np.int8)
        fit_again = np.zeros(len(at))
        _place_run(tiles, start, start, again, how_again, 0, len(at), returns, match, limits,
                   np.ones(len(at), dtype=np.bool_), lambda k: None, fit_again, rasters=rasters)  # fmt: skip
        better = (how_again == PLACED) & ((how[at] != PLACED) | (fit_again > fit[at]))
        poses[at[better]] = again[better]
        how[at[better]] = PLACED
        fit[at[better]] = fit_again[better]


def _second_starts(between: np.ndarray, before: np.ndarray, after: np.ndarray) -> list[np.ndarray]:
    """The second start's poses (each (M, 3)): every position and every heading of the interpolated pose
    between the placed scans around each scan and of those two scans. A lost odometry reading hides how the
    motion was shared out between the scans: turned in place and then driven on (a dropout at a corner),
    the scan stands where the one before it stood, which the interpolated position misses by up to the
    whole step; a turn made in one of the two steps leaves the interpolated heading half of it off, beyond
    the fine climb's reach at a few metres' range."""
    poses = (between, before, after)
    starts = []
    for position in poses:
        for heading in poses:
            start = np.empty_like(between)
            start[:, :2] = position[:, :2]
            start[:, 2] = heading[:, 2]
            starts.append(start)
    return starts


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


BATCH = 256
"""Scans handed to the compiled placement at once, at least (and the progress reported after each batch):
a batch goes on to the next anchored scan, so that `Retrack`'s segments lie in one batch ..."""
MAX_BATCH = 4 * BATCH
"""... up to this many."""

RASTER_SLACK_M = 1.0
"""How far a placement raster reaches beyond the match window that asked for it (`_place_batch`)."""


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
    fit: np.ndarray,
    unplaced: dict[int, tuple[np.ndarray, float]] | None = None,
    suspect: np.ndarray | None = None,
    rasters: int = 1,
    retrack: Retrack | None = None,
) -> tuple[np.ndarray, int]:
    """Place the scans a to b - 1 (`poses`, `how` written in place); scan a and the anchored ones start from
    their recorded pose, the others from the scan before as placed, moved as `path` moves. The scans are
    read here and placed in batches by one compiled call each (`_place_batch`), a batch ending before an
    anchored scan where it can; with `retrack`, each anchored scan after a is placed again from its tracked
    start where that differs (`Retrack`), with the scans up to the next anchored one. The returns of the
    scans not placed, and of the `suspect` ones, are kept in `unplaced` (when given) for a second start.
    Returns, with `retrack`, the pose of scan b - 1 as the first pass placed it (the tracked start of the run
    after it), and how many segments the retrack kept."""
    anchor = np.ones(len(recorded), dtype=np.bool_) if anchored is None else np.asarray(anchored, dtype=np.bool_)
    parameters = match.parameters()
    shifts = raster_shifts(rasters, match.cell_m)
    grids = np.full((len(shifts), 0), _EMPTY, dtype=np.int32)
    sums = np.empty((len(shifts), len(tiles.xy) + 1, 3))
    touched = np.empty((len(shifts), len(tiles.xy) + 1), dtype=np.int64)
    pending: list[tuple[np.ndarray, float]] = []
    first_pass_end = np.zeros(3)  # with `retrack`: the first pass's pose of the scan before the batch
    again: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None  # retrack's scratch
    kept = 0  # segments the retrack kept

    def compiled(begin: int, offsets: np.ndarray, first: int, start_at: int, rec: np.ndarray, out: tuple,
                 ends: np.ndarray, score_inv: np.ndarray) -> None:  # fmt: skip
        """`_place_batch` over the scans first + begin ... (offsets into ends), growing the rasters as asked."""
        nonlocal grids
        out_poses, out_how, out_fit = out
        i = begin
        while i < len(offsets) - 1:
            i, cells = _place_batch(
                tiles.xy, tiles.p, tiles.key, tiles.origin[0], tiles.origin[1], tiles.tile_m, tiles.rows, tiles.cols,
                ends, score_inv, offsets, first, i, start_at, anchor, rec, path, out_poses, out_how,
                match.cell_m, match.kernel, match.min_p, match.margin_m, parameters, match.climb_stride,
                match.fine_stride, limits.min_returns, limits.min_hit_fraction, limits.max_shift_m, limits.max_turn_rad,
                shifts, grids, sums, touched, out_fit,
            )  # fmt: skip
            if i < len(offsets) - 1:  # scan i's window needs larger rasters (as `MatchWorkspace.reserve`)
                grids = np.full((len(shifts), int(cells * 1.25) + 1), _EMPTY, dtype=np.int32)

    def place_again(first: int, count: int, before: np.ndarray, offsets: np.ndarray, ends: np.ndarray,
                    score_inv: np.ndarray) -> None:  # fmt: skip
        """`Retrack`: each anchored scan k after a among scans first ... first + count - 1 whose segment ends
        in the batch, placed with its segment from the tracked start (the first pass's pose of scan k - 1,
        `before[k - first]`, moved along `path`) where that differs from the recorded one."""
        nonlocal again, kept
        for k in range(max(first, a + 1), first + count):
            if not anchor[k]:
                continue
            e = _segment_end(anchor, k, first + count)
            if e == first + count and e < b and not anchor[e]:
                break  # the segment goes on into the next batch (one cut at MAX_BATCH): left as it is
            tracked = retrack.start(before[k - first], path, recorded, k)
            if tracked is None:
                continue
            if again is None:
                again = (recorded.copy(), np.empty_like(poses), np.empty_like(how), np.empty_like(fit))
            rec, alt_poses, alt_how, alt_fit = again
            rec[k] = tracked
            alt_how[k:e] = BETWEEN
            alt_fit[k:e] = 0.0
            i0, i1 = k - first, e - first
            compiled(0, offsets[i0 : i1 + 1], k, k, rec, (alt_poses, alt_how, alt_fit), ends, score_inv)
            rec[k] = recorded[k]
            if _keeps(before[k - first], path, recorded, k, e, (poses, fit), (alt_poses, alt_fit)):
                poses[k:e], how[k:e], fit[k:e] = alt_poses[k:e], alt_how[k:e], alt_fit[k:e]
                kept += 1

    def place(first: int) -> None:
        nonlocal first_pass_end
        ends = np.concatenate([e for e, _ in pending]) if pending else np.zeros((0, 2))
        counts = np.array([len(e) for e, _ in pending], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        rng = np.hypot(ends[:, 0], ends[:, 1])
        widths = [inc if match.score_sigma_rad is None else match.score_sigma_rad for _, inc in pending]
        sigma_rad = np.repeat(np.asarray(widths, dtype=float), counts)
        # as `match_and_weigh`: the score's width at each return
        score_inv = 0.5 / (match.score_sigma_m**2 + (rng * sigma_rad) ** 2)
        compiled(0, offsets, first, a, recorded, (poses, how, fit), ends, score_inv)
        if retrack is not None:
            before = np.empty((len(pending) + 1, 3))  # the first pass's poses of scans first - 1 ...
            before[0] = first_pass_end
            before[1:] = poses[first : first + len(pending)]
            place_again(first, len(pending), before, offsets, ends, score_inv)
            first_pass_end = before[-1]
        if unplaced is not None:
            for j, scan in enumerate(pending):
                if how[first + j] == BETWEEN or (suspect is not None and suspect[first + j]):
                    unplaced[first + j] = scan

    read = a  # scans read so far: a to read - 1
    for pts, increment_rad in scans:
        if read >= b:
            raise ValueError(f"more scans than recorded poses ({len(recorded)})")
        if len(pending) >= MAX_BATCH or (len(pending) >= BATCH and anchor[read]):
            report(read - len(pending) - a)
            place(read - len(pending))
            pending = []
        pending.append((np.asarray(pts, dtype=float).reshape(-1, 2), float(increment_rad)))
        read += 1
    if pending:
        report(read - len(pending) - a)
        place(read - len(pending))
    if read != b:
        raise ValueError(f"{read - a} scans for the {b - a} recorded poses {a} to {b - 1}")
    return first_pass_end, kept


@njit(cache=True, nogil=True)
def _tile_ranges(key, rows, cols, origin_x, origin_y, tile_m, x0, y0, x1, y1, lo, hi):  # pragma: no cover - compiled
    """The map points of the tiles that the box [x0, x1] x [y0, y1] touches, as index ranges lo[c]:hi[c] into
    `MapTiles`' sorted arrays, one per column of tiles, in order; returns how many (0: the box misses the map)."""
    ix0 = max(0, int(math.floor((x0 - origin_x) / tile_m)))
    ix1 = min(cols - 1, int(math.floor((x1 - origin_x) / tile_m)))
    iy0 = max(0, int(math.floor((y0 - origin_y) / tile_m)))
    iy1 = min(rows - 1, int(math.floor((y1 - origin_y) / tile_m)))
    if ix1 < ix0 or iy1 < iy0:
        return 0
    n = 0
    for ix in range(ix0, ix1 + 1):
        lo[n] = np.searchsorted(key, ix * rows + iy0, side="left")
        hi[n] = np.searchsorted(key, ix * rows + iy1, side="right")
        n += 1
    return n


@njit(cache=True, nogil=True)
def _place_batch(tile_xy, tile_p, key, origin_x, origin_y, tile_m, rows, cols, ends, score_inv, offsets,
                 first, begin, a, anchored, recorded, path, poses, how, cell_m, kernel, min_p, margin, match,
                 climb_stride, fine_stride, min_returns, min_hit_fraction, max_shift, max_turn, shifts, grids,
                 sums, touched, fit):  # pragma: no cover - compiled  # fmt: skip
    """Place the scans first, first + 1, ... (their returns ends[offsets[i]:offsets[i + 1]]) in turn, as
    `match_and_weigh` matches one particle: the start (recorded at anchored scans and at a, else the scan
    before as placed moved along `path`), the fine climb and the Gauss-Newton finish on the map's points
    rasterised around the start's match window (its returns' box grown by `margin`), the match kept or not
    (`PlacementLimits`).

    One raster per row of `shifts` (its cell lattice shifted by that much in x and y from the map frame's):
    the climb and the finish on the first, the finish alone from there on each of the others, and the
    match's pose the mean of theirs. A raster's cells summarise the points by their cell's mean, so a match
    moves with where the cell edges fall by up to a few millimetres; rasters with their edges at different
    places each err in their own way, and their mean less. A raster is kept for the next scans while their
    match windows lie inside it: it reaches RASTER_SLACK_M beyond the window that asked for it, so that a
    scan a few centimetres on from the one before reads the same cells instead of rasterising most of the
    map again.

    `poses`, `how` and `fit` (a kept match's score per return, on the first raster) written in place.
    Starts at the batch's scan `begin`; returns (the scans of the batch done, 0), or (i, cells) when scan
    i's window needs rasters of that many cells, more than `grids` have: the caller grows them and calls
    again from i. `grids` are left empty either way."""
    lo = np.empty(cols, dtype=np.int64)
    hi = np.empty(cols, dtype=np.int64)
    start = np.empty(3)
    mean = np.empty(3)
    n = offsets.shape[0] - 1
    m = shifts.shape[0]
    used = np.zeros(m, dtype=np.int64)
    x0 = np.zeros(m)  # raster j's window (x0[j], y0[j], nx[j], ny[j]); nx[j] 0: none made yet
    y0 = np.zeros(m)
    nx = np.zeros(m, dtype=np.int64)
    ny = np.zeros(m, dtype=np.int64)
    for i in range(begin, n):
        k = first + i
        if anchored[k] or k == a:
            start[0], start[1], start[2] = recorded[k, 0], recorded[k, 1], recorded[k, 2]
        else:
            start[0], start[1], start[2] = compose_compiled(poses[k - 1], between_compiled(path[k - 1], path[k]))
        poses[k, 0], poses[k, 1], poses[k, 2] = start[0], start[1], start[2]  # the next start if not matched
        o0, o1 = offsets[i], offsets[i + 1]
        if o1 - o0 < min_returns:
            how[k] = 2  # NO_RETURNS
            continue
        e, w = ends[o0:o1].copy(), score_inv[o0:o1].copy()
        rx0, ry0, rx1, ry1 = end_point_box(start[0], start[1], math.cos(start[2]), math.sin(start[2]), e)
        wx0, wy0, wx1, wy1 = rx0 - margin, ry0 - margin, rx1 + margin, ry1 + margin  # the match's window
        for j in range(m):
            if (nx[j] > 0 and wx0 >= x0[j] and wy0 >= y0[j] and wx1 <= x0[j] + (nx[j] - 1) * cell_m
                    and wy1 <= y0[j] + (ny[j] - 1) * cell_m):  # fmt: skip
                continue
            grid = grids[j]
            _empty(grid, touched[j], used[j])
            used[j] = 0
            x0[j] = math.floor((wx0 - RASTER_SLACK_M - shifts[j, 0]) / cell_m) * cell_m + shifts[j, 0]
            y0[j] = math.floor((wy0 - RASTER_SLACK_M - shifts[j, 1]) / cell_m) * cell_m + shifts[j, 1]
            nx[j] = int(math.ceil((wx1 + RASTER_SLACK_M - x0[j]) / cell_m) + 1)
            ny[j] = int(math.ceil((wy1 + RASTER_SLACK_M - y0[j]) / cell_m) + 1)
            if nx[j] * ny[j] > grid.shape[0]:
                _empty_all(grids, touched, used)
                return i, nx[j] * ny[j]
            n_ranges = _tile_ranges(key, rows, cols, origin_x, origin_y, tile_m, x0[j], y0[j],
                                    x0[j] + nx[j] * cell_m, y0[j] + ny[j] * cell_m, lo, hi)  # fmt: skip
            for r in range(n_ranges):  # the tiles' points, in `MapTiles`' order, as one `_rasterise`
                used[j] = _rasterise_range(tile_xy, tile_p, lo[r], hi[r], min_p, x0[j], y0[j], nx[j], ny[j],
                                           cell_m, grid, sums[j], touched[j], used[j])  # fmt: skip
            _to_means(sums[j], used[j])
        if used[0] == 0:
            continue  # no map near the scan: it is placed between matched neighbours
        ce, cw = e, w  # the climb's returns and the fine levels' (`scanmatch._every`)
        if climb_stride > 1:
            ce, cw = e[::climb_stride].copy(), w[::climb_stride].copy()
        fe, fw = ce, cw
        if fine_stride > 1:
            fe, fw = ce[::fine_stride].copy(), cw[::fine_stride].copy()
        pose = start.copy()
        result = _fine_climb(pose, ce, cw, fe, fw, e, w, x0[0], y0[0], nx[0], ny[0], cell_m, kernel, grids[0],
                             sums[0], match)  # fmt: skip
        if m > 1:
            mean[:] = 0.0
            for j in range(1, m):
                other = pose.copy()
                _finish(other, e, x0[j], y0[j], nx[j], ny[j], cell_m, kernel, grids[j], sums[j], w, match[7],
                        match[4], match[5], match[6], int(match[11]), match[12], match[12])  # fmt: skip
                mean[0] += other[0] - pose[0]
                mean[1] += other[1] - pose[1]
                mean[2] += wrap_angle_scalar(other[2] - pose[2])
            pose[0] += mean[0] / m
            pose[1] += mean[1] / m
            pose[2] = wrap_angle_scalar(pose[2] + mean[2] / m)
        shift = math.hypot(pose[0] - start[0], pose[1] - start[1])
        turn = abs(wrap_angle_scalar(pose[2] - start[2]))
        if result[2] >= min_hit_fraction * (o1 - o0) and shift <= max_shift and turn <= max_turn:
            poses[k, 0], poses[k, 1], poses[k, 2] = pose[0], pose[1], pose[2]
            how[k] = 0  # PLACED
            fit[k] = result[0] / (o1 - o0)
    _empty_all(grids, touched, used)
    return n, 0


@njit(cache=True, nogil=True)
def _empty(grid, touched, used):  # pragma: no cover - compiled
    """A raster's `used` occupied cells (their slots in `touched`) back to empty."""
    for slot in range(used):
        grid[touched[slot]] = _EMPTY


@njit(cache=True, nogil=True)
def _empty_all(grids, touched, used):  # pragma: no cover - compiled
    """Every raster's occupied cells back to empty."""
    for j in range(grids.shape[0]):
        _empty(grids[j], touched[j], used[j])
        used[j] = 0


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
    out[free] = interpolate(from_a, from_b, w)
    return out
