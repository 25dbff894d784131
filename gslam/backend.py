"""The back end under the filter: a pose graph over the run, closed by scans matched far back in time.

Nodes are scans of the front end's trajectory (the placed one, once the run is over), one each
`node_travel_m` of path or `node_turn_rad` of turn. Consecutive nodes are tied by the front end's relative
pose (`sequential` edges, their uncertainty growing with the motion between them). Every `submap_nodes`
nodes make a submap: their scans drawn in the first one's frame at the front end's poses
(`gslam.loopclosure.Submap`). Every `search_every`-th node's scan is searched for in the submaps that lie
near its current estimate but were left at least `min_separation_m` of travel before (closer ones are the
filter's own business): the whole window of `ClosureSettings` is searched by branch and bound, not only a
step around the estimate, so a closure is found even where the drift has grown to metres.

A match is checked three times before it counts: it must score `min_score`; no pose `ambiguity_m` away
may score nearly as well (`gslam.loopclosure.Match.ambiguous`: corridors, repeated rooms); and another
node's closure near it in time must agree with it (`confirm_nodes`). It then enters the graph under a
Huber loss; the graph is optimised (`gslam.posegraph.optimise_robust`, which drops the closures that still
disagree with the rest) as soon as a closure the estimate misses enters, else at the end.

The optimised node poses correct the whole trajectory (`correct_trajectory`: a scan between two nodes
keeps its front-end pose relative to each, the two blended by its place between them) and the map
(`correct_points`), but only where the front end is wrong: when enough of the closures are missed by
the front end's own poses (`min_inconsistent`); otherwise the closures confirm it and it is left as it was
(`finish`).
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from gslam.loopclosure import ClosureSettings, Match, Submap, match_scan, voxel_filter
from gslam.motion import wrap_angle
from gslam.posegraph import CLOSURE, PREVIOUS, SEQUENTIAL, Edge, optimise_robust, residuals
from gslam.scan import transform_points
from gslam.se2 import compose, interpolate, inverse


@dataclass(frozen=True)
class BackEndSettings:
    """The back end's defaults (docs/CHOICES.md, "Back end")."""

    node_travel_m: float = 0.5
    node_turn_rad: float = 0.5
    submap_nodes: int = 10
    """Nodes per submap."""
    min_separation_m: float = 20.0
    """Travel between a submap's last node and a node searched in it: nearer in time is the filter's job."""
    search_radius_m: float = 5.0
    """A submap is a candidate when one of its nodes is this near the node's current estimate."""
    max_candidates: int = 1
    """Submaps searched per node (the nearest ones)."""
    search_every: int = 2
    """Search for closures at every n-th node."""
    sequential_sigma_xy_m: float = 0.02
    sequential_sigma_xy_per_m: float = 0.02
    sequential_sigma_phi_rad: float = 0.005
    sequential_sigma_phi_per_rad: float = 0.005
    confirm_nodes: int = 6
    confirm_m: float = 0.2
    confirm_rad: float = 0.05
    """A closure enters the graph once another one, from a node at most `confirm_nodes` away, agrees with
    it: both move their node to within `confirm_m` and `confirm_rad` of each other. A single match, however
    good its score, may be a look-alike place; a place found again from the next nodes is not."""
    closure_sigma_xy_m: float = 0.05
    closure_sigma_phi_rad: float = 0.01
    optimise_chi2: float = 9.0
    """The graph is optimised as soon as a closure enters it that the current estimate misses by more than
    this (its whitened squared residual: 3 sigma); the closures the estimate already agrees with wait for
    the end of the run (or for `optimise_closures` of them): optimising for them would move little."""
    optimise_closures: int = 50
    optimise_gap_nodes: int = 1
    """Nodes at least between two optimisations (the one at the end aside): 1 optimises for each closure
    the estimate misses as it comes; the live graph (`gslam.livebackend`), whose front-end poses miss more
    of them, waits a few nodes and optimises for several at once."""
    inconsistent_chi2: float = 9.0
    min_inconsistent: int = 5
    min_inconsistent_fraction: float = 0.05
    """The graph corrects the front end only where the front end is wrong: when at least `min_inconsistent`
    of the closures kept, and `min_inconsistent_fraction` of them, are missed by the front end's own poses
    by more than `inconsistent_chi2` (whitened squared residual: 3 sigma; a right closure, measured with
    the sigmas assumed, is missed so in 3 % of cases). Otherwise the closures confirm the front end and
    the trajectory is left as it was: its local precision is finer than a closure's (docs/CHOICES.md)."""
    huber_k: float = 1.0
    reject_chi2: float = 16.0
    cached_submaps: int = 4
    """Submap fields kept built (each a few MB); the others are rebuilt when searched again."""
    locate_region_m: float = 8.0
    locate_margin_m: float = 1.0
    """`locate` searches the map in regions: a grid of `locate_region_m` over the nodes, each region's field
    built of the returns of the nodes within twice it (a scan's view whole), searched half the spacing and
    `locate_margin_m` around its centre (every place lies in some region's window)."""
    locate_heading_range_m: float = 5.0
    """`locate`'s heading step moves a return at this range by one cell (0.01 rad; the closures' 10 m, 0.005
    rad, took the search 1.8 times as long on mit-csail for the same poses after refinement)."""
    session_sigma_xy_m: float = 0.5
    session_sigma_phi_rad: float = 0.1
    """The link between the last node of one mapping run and the first of the run that continues it
    (`begin_session`): where the new run found itself in the old map, loosely, so that the closures
    between the runs, not the start, say how they fit."""
    closure: ClosureSettings = field(default_factory=ClosureSettings)


class PreviousGraph(NamedTuple):
    """The graph of earlier mapping runs, as `PoseGraphBackEnd.add_previous` takes it."""

    poses: np.ndarray
    """(M, 3) the nodes' optimised laser poses."""
    points_world: list[np.ndarray]
    """Each node's returns (K, 2) in the map frame."""
    steps: np.ndarray
    """(M,) each node's step in its own run."""
    sessions: np.ndarray
    """(M,) the run each node belongs to (0: the first)."""
    closures: list[tuple[int, int]]
    closure_scores: list[float]


@dataclass
class ClosureRecord:
    """A closure searched and found: its edge (from the submap's first node, the anchor, to the node; the
    match's pose and score), the submap, and whether it was confirmed, kept or rejected."""

    edge: Edge
    submap: int
    kept: bool = False
    """In the graph (confirmed) and not rejected by the optimisation."""
    confirmed: bool = False
    rejected: bool = False

    @property
    def node(self) -> int:
        return self.edge.j

    @property
    def anchor(self) -> int:
        return self.edge.i

    @property
    def score(self) -> float:
        return self.edge.score


class PoseGraphBackEnd:
    """Nodes added one at a time (`add_node`), closures searched as they come, the graph optimised."""

    def __init__(self, settings: BackEndSettings = BackEndSettings(), first_session: int = 0) -> None:
        """`first_session`: the number of the mapping run the first node of this run belongs to, after the
        earlier runs (`add_previous`, and those in other maps, which are not in this graph)."""
        self.settings = settings
        self.steps: list[int] = []  # the step (scan index in the run) of each node
        self.front: list[np.ndarray] = []  # the front end's pose of each node
        self.points: list[np.ndarray] = []  # each node's returns (sensor frame), voxel filtered
        self.travel: list[float] = []  # path length up to each node
        self.estimate = np.empty((0, 3))  # the graph's current pose of each node
        self.edges: list[Edge] = []
        self.submaps: list[tuple[int, int]] = []  # node ranges [a, b) of the finished submaps
        self._fields: OrderedDict[int, Submap] = OrderedDict()
        self.closures: list[ClosureRecord] = []
        self.searches = 0
        self.ambiguous = 0  # searches whose best match had a rival elsewhere in the window
        self.search_s = 0.0
        self.optimisations: list[float] = []  # seconds each
        self._unoptimised = 0  # closures added since the last optimisation
        self._urgent = False  # a closure waits that the estimate misses (`optimise_chi2`)
        self._optimised_at = -(10**9)  # the node count at the last optimisation
        self._session_start = 0  # the first node of the current run (its searches count from it)
        self.inconsistent = 0  # closures kept that the front end misses (`finish`)
        self.applied = False  # whether the optimised graph corrects the front end (`finish`)
        self.session: list[int] = []  # the mapping run each node belongs to (0: the first)
        self._session = int(first_session)
        self._first_session = int(first_session)
        self._new_session = False  # the next node starts a run (`begin_session`)

    def __len__(self) -> int:
        return len(self.steps)

    def add_node(self, step: int, pose: np.ndarray, points_xy: np.ndarray, relative: np.ndarray | None = None) -> None:
        """A node at the front end's `pose` for the run's scan `step`, with its returns `points_xy` (sensor
        frame); ties it to the node before, closes a submap when one is full, searches for closures.
        `relative`: the front end's motion from the node before to this one, where it is not the difference
        of their poses (online, the best particle may have changed between them: its own history says how
        it moved)."""
        s = self.settings
        self._append(step, np.asarray(pose, dtype=float), self._kept_returns(points_xy), relative)
        k = len(self.steps) - 1
        if (k - self._session_start) % s.search_every == 0:
            self._search(k)

    def _kept_returns(self, points_xy: np.ndarray) -> np.ndarray:
        """A scan's returns (K, 2, sensor frame) as the graph keeps and matches them: those within the
        closures' `max_range_m`, one per `voxel_m` voxel."""
        c = self.settings.closure
        pts = np.asarray(points_xy, dtype=float).reshape(-1, 2)
        return voxel_filter(pts[np.hypot(pts[:, 0], pts[:, 1]) <= c.max_range_m], c.voxel_m)

    def _append(self, step: int, pose: np.ndarray, pts: np.ndarray, relative: np.ndarray | None = None) -> None:
        """Node k = len(self) at the front end's `pose`, tied to the node before (at the link's loose sigmas
        when it starts a mapping run); its submap closed when full."""
        s = self.settings
        k = len(self.steps)
        first = self.submaps[-1][1] if self.submaps else 0
        if self._new_session and k > first:  # a submap holds one run's scans
            self.submaps.append((first, k))
            first = k
        if k:
            rel = compose(inverse(self.front[-1]), pose) if relative is None else np.asarray(relative, dtype=float)
            if self._new_session:
                sig = np.array([s.session_sigma_xy_m, s.session_sigma_xy_m, s.session_sigma_phi_rad])
                # the runs lie apart in time: every submap of the earlier ones may be searched at once
                self.travel.append(self.travel[-1] + s.min_separation_m)
            else:
                sig = self._sequential_sigmas(rel)
                self.travel.append(self.travel[-1] + float(np.hypot(rel[0], rel[1])))
            self.edges.append(Edge(k - 1, k, rel, sig, SEQUENTIAL))
            est = compose(self.estimate[-1], rel)
        else:
            self.travel.append(0.0)
            est = pose
        self._new_session = False
        self.steps.append(int(step))
        self.session.append(self._session)
        self.front.append(pose)
        self.points.append(pts)
        self.estimate = np.vstack([self.estimate, est[None]])
        if k + 1 - first >= s.submap_nodes:
            self.submaps.append((first, k + 1))

    @property
    def run_start(self) -> int:
        """The first node of this mapping run: the nodes before it are the earlier runs' (`add_previous`)."""
        return self._session_start

    def begin_session(self) -> None:
        """The nodes added from here are a new mapping run's, continuing the graph of the earlier ones
        (`add_previous`): their first is tied to the last node before loosely (`session_sigma_xy_m`), and they
        may search every submap of the earlier runs from the start."""
        if self.steps:
            self._session = max(self.session[-1] + 1, self._first_session)
            self._new_session = True
        self._session_start = len(self.steps)

    def add_previous(
        self,
        poses: np.ndarray,
        points_world: list[np.ndarray],
        steps: np.ndarray,
        sessions: np.ndarray,
        closures: list[tuple[int, int]],
        closure_scores: list[float] | None = None,
    ) -> None:
        """The graph of earlier mapping runs, as a result saved it: its optimised node poses (M, 3, the laser's),
        each node's returns in the map frame, its step in its own run and the run it belongs to; and the node
        pairs of its closures. They enter as nodes that search nothing (they were searched in their own run),
        tied by their relative poses as optimised, each closure kept as a constraint of a closure's sigmas at
        the same, so that the old graph keeps its shape unless the new run's closures say otherwise."""
        s = self.settings
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        base = len(self.steps)
        for k in range(len(poses)):
            if k and sessions[k] != sessions[k - 1]:
                self._session = int(sessions[k - 1])
                self.begin_session()
            self._session = int(sessions[k])
            local = transform_points(inverse(poses[k]), np.asarray(points_world[k], dtype=float).reshape(-1, 2))
            self._append(int(steps[k]), poses[k], voxel_filter(local, s.closure.voxel_m))
        sig = np.array([s.closure_sigma_xy_m, s.closure_sigma_xy_m, s.closure_sigma_phi_rad])
        scores = list(closure_scores or []) + [0.0] * len(closures)
        for (i, j), score in zip(closures, scores, strict=False):
            rel = compose(inverse(poses[i]), poses[j])
            self.edges.append(Edge(base + int(i), base + int(j), rel, sig, PREVIOUS, float(score)))
        self.begin_session()

    def _sequential_sigmas(self, rel: np.ndarray) -> np.ndarray:
        """A sequential edge's sigmas (m, m, rad): growing with the motion `rel` it measures."""
        s = self.settings
        dist = float(np.hypot(rel[0], rel[1]))
        xy = s.sequential_sigma_xy_m + s.sequential_sigma_xy_per_m * dist
        return np.array([xy, xy, s.sequential_sigma_phi_rad + s.sequential_sigma_phi_per_rad * abs(float(rel[2]))])

    def refresh_front(self, front: np.ndarray) -> None:
        """Take the front end's poses of the nodes (M, 3) as they stand now: a particle filter's best
        history is rewritten as the run goes (resampling keeps the particles that fit). The sequential edges
        are measured again from them, and the submaps not yet built are drawn at them; the closures and the
        submaps built stand (each spans a few metres, which a rewrite hardly bends)."""
        s = self.settings
        front = np.asarray(front, dtype=float).reshape(-1, 3)
        self.front = list(front)
        rel = compose(inverse(front[:-1]), front[1:])
        xy = s.sequential_sigma_xy_m + s.sequential_sigma_xy_per_m * np.hypot(rel[:, 0], rel[:, 1])
        phi = s.sequential_sigma_phi_rad + s.sequential_sigma_phi_per_rad * np.abs(rel[:, 2])
        sig = np.column_stack([xy, xy, phi])
        for k, e in enumerate(self.edges):
            if e.kind == SEQUENTIAL:
                self.edges[k] = Edge(e.i, e.j, rel[e.i], sig[e.i], SEQUENTIAL)

    def _field(self, m: int) -> Submap:
        sub = self._fields.get(m)
        if sub is not None:
            self._fields.move_to_end(m)
            return sub
        a, b = self.submaps[m]
        base = inverse(self.front[a])
        parts = [transform_points(compose(base, self.front[n]), self.points[n]) for n in range(a, b)]
        pts = np.concatenate(parts) if parts else np.empty((0, 2))
        sub = Submap.build(pts if len(pts) else np.zeros((1, 2)), self.settings.closure)
        self._fields[m] = sub
        if len(self._fields) > self.settings.cached_submaps:
            self._fields.popitem(last=False)
        return sub

    def _candidates(self, k: int) -> list[int]:
        """The submaps to search node `k` in: left `min_separation_m` of travel before it, one of their
        nodes within `search_radius_m` of its estimate; the nearest `max_candidates` of them."""
        s = self.settings
        if not self.submaps:
            return []
        bounds = np.asarray(self.submaps)
        travel = np.asarray(self.travel)
        far = np.flatnonzero(travel[k] - travel[bounds[:, 1] - 1] >= s.min_separation_m)
        if len(far) == 0:
            return []
        # the submaps are consecutive runs of nodes: the nearest node of each, from one pass over them
        end = int(bounds[far[-1], 1])
        d = np.hypot(*(self.estimate[:end, :2] - self.estimate[k, :2]).T)
        nearest = np.minimum.reduceat(d, bounds[: far[-1] + 1, 0])[far]
        near = np.flatnonzero(nearest <= s.search_radius_m)
        order = near[np.argsort(nearest[near], kind="stable")]
        return [int(far[i]) for i in order[: s.max_candidates]]

    def _search(self, k: int) -> None:
        s = self.settings
        pts = self.points[k]
        if len(pts) < 10:
            return
        for m in self._candidates(k):
            a = self.submaps[m][0]
            t0 = time.perf_counter()
            guess = compose(inverse(self.estimate[a]), self.estimate[k])
            match = match_scan(self._field(m), pts, guess, s.closure)
            self.searches += 1
            self.search_s += time.perf_counter() - t0
            if match is None:
                continue
            if match.ambiguous:
                self.ambiguous += 1
                continue
            sig = np.array([s.closure_sigma_xy_m, s.closure_sigma_xy_m, s.closure_sigma_phi_rad])
            edge = Edge(a, k, match.pose, sig, CLOSURE, match.score)
            record = ClosureRecord(edge, m)
            self.closures.append(record)
            self._confirm(record)
        if (self._urgent or self._unoptimised >= s.optimise_closures) and (
            len(self.steps) - self._optimised_at >= s.optimise_gap_nodes
        ):
            self.optimise()

    def locate(self, scans: list[np.ndarray], workers: int = 1) -> list[tuple[np.ndarray, float] | None]:
        """Where each scan (its returns (K, 2) in the sensor frame) stands in the graph's map when nothing is
        known of its pose, as Cartographer finds a new trajectory in an old map: searched by branch and bound
        over every heading and the whole map, region by region (`_regions`: the returns of every node within
        twice `locate_region_m` of a point of a grid of that spacing, so that a scan's view is in the field
        whole, not a submap's few metres of it). Per scan, (its pose in the map frame, its score), or None where no
        region holds a match that scores `min_score`, or a match as good stands elsewhere (`ambiguity_m`,
        `ambiguity_ratio`: a look-alike place, in the same region or another). `workers` threads search
        regions at once (the search is compiled code that runs without the GIL), each building its own
        region's field, so at most that many fields are held; the answer does not depend on them."""
        s = self.settings
        clouds = [self._kept_returns(points_xy) for points_xy in scans]
        found: list[list[tuple[np.ndarray, float, bool]]] = [[] for _ in scans]
        settings = replace(
            s.closure,
            window_m=0.5 * s.locate_region_m + s.locate_margin_m,
            window_rad=math.pi,
            heading_range_m=s.locate_heading_range_m,
        )

        def search(region: tuple[np.ndarray, np.ndarray]) -> list[tuple[int, Match]]:
            centre, near = region
            field = self._region_field(near)
            if field is None:
                return []
            guess = np.array([centre[0], centre[1], 0.0])
            matches = ((k, match_scan(field, pts, guess, settings)) for k, pts in enumerate(clouds) if len(pts) >= 10)
            return [(k, match) for k, match in matches if match is not None]

        regions = list(self._regions())
        if workers > 1 and len(regions) > 1:
            with ThreadPoolExecutor(min(workers, len(regions)), thread_name_prefix="gslam-locate") as pool:
                per_region = list(pool.map(search, regions))  # in the regions' order, whichever thread ran them
        else:
            per_region = [search(region) for region in regions]
        for matches in per_region:
            for k, match in matches:
                found[k].append((match.pose, match.score, match.ambiguous))
        return [self._unambiguous(f) for f in found]

    def _unambiguous(self, found: list[tuple[np.ndarray, float, bool]]) -> tuple[np.ndarray, float] | None:
        """The best of a scan's matches in the regions, unless its own region holds a rival (`Match.ambiguous`)
        or another region a match as good `ambiguity_m` from it."""
        if not found:
            return None
        c = self.settings.closure
        found = sorted(found, key=lambda f: -f[1])
        pose, score, rival = found[0]
        if rival:
            return None
        for other, other_score, _ in found[1:]:
            apart = math.hypot(other[0] - pose[0], other[1] - pose[1]) >= c.ambiguity_m
            if apart and other_score >= c.ambiguity_ratio * score:
                return None  # the same scan fits another place nearly as well
        return pose, score

    def _regions(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """(centre (2,), nodes) of each region of the map `locate` searches: the points of a grid of spacing
        `locate_region_m` over the nodes' positions that have a node within that distance, each with the
        nodes within twice it, whose returns make its field (`_region_field`)."""
        s = self.settings
        est = np.asarray(self.estimate).reshape(-1, 3)
        if len(est) == 0:
            return
        step = s.locate_region_m
        lo = np.floor(est[:, :2].min(axis=0) / step) * step
        hi = est[:, :2].max(axis=0)
        for x in np.arange(lo[0], hi[0] + step, step):
            for y in np.arange(lo[1], hi[1] + step, step):
                d = np.hypot(est[:, 0] - x, est[:, 1] - y)
                if np.any(d <= step):
                    yield np.array([x, y]), np.flatnonzero(d <= 2 * step)

    def _region_field(self, nodes: np.ndarray) -> Submap | None:
        """The field of a region of `locate`: the returns (map frame) of its `nodes`; None if they hold none."""
        est = np.asarray(self.estimate).reshape(-1, 3)
        pts = np.concatenate([transform_points(est[k], self.points[k]) for k in nodes])
        return Submap.build(pts, self.settings.closure) if len(pts) else None

    def _where(self, c: ClosureRecord) -> np.ndarray:
        """Where closure `c` puts its node, by the current estimate of its anchor."""
        return compose(self.estimate[c.anchor], c.edge.measured)

    def _confirm(self, new: ClosureRecord) -> None:
        """Put `new` and the closures near it in time that agree with it into the graph (`confirm_nodes`)."""
        s = self.settings
        agree = []
        for c in self.closures[:-1]:
            if c.rejected or abs(c.node - new.node) > s.confirm_nodes:
                continue
            # both closures' corrections, carried to the new node along the current estimate
            moved = compose(self._where(c), compose(inverse(self.estimate[c.node]), self.estimate[new.node]))
            here = self._where(new)
            if (
                math.hypot(moved[0] - here[0], moved[1] - here[1]) <= s.confirm_m
                and abs(wrap_angle(moved[2] - here[2])) <= s.confirm_rad
            ):
                agree.append(c)
        if not agree:
            return
        for c in [*agree, new]:
            if c.confirmed:
                continue
            c.confirmed = c.kept = True
            self.edges.append(c.edge)
            self._unoptimised += 1
            if residuals(self.estimate, [c.edge])[0] > s.optimise_chi2:
                self._urgent = True

    def optimise(self) -> None:
        """Optimise the graph from its current estimate; closures it rejects are taken out of the graph."""
        s = self.settings
        result = optimise_robust(self.estimate, self.edges, s.huber_k, s.reject_chi2)
        self.optimisations.append(result.seconds)
        if result.rejected:
            gone = set(result.rejected)
            gone_edges = {id(self.edges[k]) for k in gone}
            for rec in self.closures:
                if id(rec.edge) in gone_edges:
                    rec.kept = False
                    rec.rejected = True
            self.edges = [e for k, e in enumerate(self.edges) if k not in gone]
        self.estimate = result.poses
        self._unoptimised = 0
        self._urgent = False
        self._optimised_at = len(self.steps)

    def finish(self) -> None:
        """Optimise once more if closures wait; then decide whether the graph corrects the front end at all
        (`min_inconsistent`): if not, the node estimates are set back to the front end's poses."""
        if self._unoptimised:
            self.optimise()
        self.inconsistent, self.applied = self.judge_front_end()
        if not self.applied:
            self.estimate = np.asarray(self.front, dtype=float).reshape(-1, 3).copy()

    def judge_front_end(self, front: np.ndarray | None = None) -> tuple[int, bool]:
        """(closures kept that the front end's own poses miss, whether that is enough for the graph to
        correct the front end): the gate of `min_inconsistent` and `min_inconsistent_fraction`. `front`: the
        front end's poses of the nodes (default: those they were added at)."""
        s = self.settings
        kept = [c.edge for c in self.closures if c.kept]
        poses = np.asarray(self.front if front is None else front, dtype=float).reshape(-1, 3)
        misses = residuals(poses, kept) if kept else np.empty(0)
        missed = int(np.sum(misses > s.inconsistent_chi2))
        return missed, missed >= s.min_inconsistent and missed >= s.min_inconsistent_fraction * len(kept)

    def node_steps(self, front_poses: np.ndarray) -> np.ndarray:
        """The steps of a trajectory (T, 3) that make nodes: the first, then each one that has moved
        `node_travel_m` or turned `node_turn_rad` from the last node."""
        s = self.settings
        out = []
        last = None
        for t, pose in enumerate(np.asarray(front_poses, dtype=float)):
            if (
                last is None
                or math.hypot(pose[0] - last[0], pose[1] - last[1]) >= s.node_travel_m
                or abs(wrap_angle(pose[2] - last[2])) >= s.node_turn_rad
            ):
                out.append(t)
                last = pose
        return np.asarray(out, dtype=np.int64)

    def correct_points(self, xy: np.ndarray) -> np.ndarray:
        """Map points (K, 2, in the front end's frame) moved with the graph: each with the node whose
        scan's returns (at the front end's pose) lie nearest it."""
        from scipy.spatial import cKDTree

        if len(xy) == 0 or not self.steps:
            return xy.copy()
        ends = [transform_points(self.front[k], self.points[k]) for k in range(len(self.steps))]
        owner = np.concatenate([np.full(len(e), k) for k, e in enumerate(ends)])
        if len(owner) == 0:
            return xy.copy()
        _, nearest = cKDTree(np.concatenate(ends)).query(xy)
        return move_with_nodes(xy, owner[nearest], np.asarray(self.front), np.asarray(self.estimate))

    def graph(self) -> dict:
        """The graph for the outputs (`SLAM_GRAPH_SCHEMA`): optimised node poses, steps, edges, closures."""
        kept = [c for c in self.closures if c.kept]
        rejected = [c for c in self.closures if c.rejected]
        previous = [e for e in self.edges if e.kind == PREVIOUS]  # an earlier run's closures
        est = np.asarray(self.estimate).reshape(-1, 3)
        return {
            "x_m": est[:, 0].tolist(),
            "y_m": est[:, 1].tolist(),
            "yaw_rad": est[:, 2].tolist(),
            "step": [int(s) for s in self.steps],
            "session": [int(s) for s in self.session],
            "sequential": [[e.i, e.j] for e in self.edges if e.kind == SEQUENTIAL],
            "closures": [[c.anchor, c.node] for c in kept] + [[e.i, e.j] for e in previous],
            "closure_scores": [round(c.score, 4) for c in kept] + [round(e.score, 4) for e in previous],
            "rejected": [[c.anchor, c.node] for c in rejected],
            "rejected_scores": [round(c.score, 4) for c in rejected],
        }

    def summary(self) -> dict:
        """What the result records of the graph: sizes, closures (found, kept, rejected, their scores)
        and the time of the searches and the optimisations."""
        kept = [c for c in self.closures if c.kept]
        rejected = [c for c in self.closures if c.rejected]
        return {
            "nodes": len(self.steps),
            "sessions": len(set(self.session)),
            "nodes_of_earlier_runs": sum(n != self._session for n in self.session),
            "closures_between_runs": sum(self.session[c.anchor] != self.session[c.node] for c in kept),
            "submaps": len(self.submaps),
            "sequential_edges": sum(e.kind == SEQUENTIAL for e in self.edges),
            "searches": self.searches,
            "ambiguous": self.ambiguous,
            "closures_found": len(self.closures),
            "closures_kept": len(kept),
            "closures_unconfirmed": sum(not c.confirmed for c in self.closures),
            "closures_rejected": len(rejected),
            "closures_missed_by_front_end": self.inconsistent,
            "applied": self.applied,
            "kept_score_mean": float(np.mean([c.score for c in kept])) if kept else None,
            "rejected_score_mean": float(np.mean([c.score for c in rejected])) if rejected else None,
            "search_s": round(self.search_s, 3),
            "optimisations": len(self.optimisations),
            "optimise_s": round(float(sum(self.optimisations)), 3),
        }

    def correct_trajectory(self, front_poses: np.ndarray, session: int | None = None) -> np.ndarray:
        """Every step's pose (T, 3) of a mapping run (default: the last) moved with its optimised nodes: each
        scan's front-end pose relative to the node before and the node after, blended by its place between
        them."""
        run = self.session[-1] if session is None and self.session else session
        mine = np.flatnonzero(np.asarray(self.session) == run) if self.session else np.empty(0, dtype=int)
        front = np.asarray(self.front).reshape(-1, 3)
        return correct_between(front_poses, np.asarray(self.steps)[mine], front[mine], self.estimate[mine])


def move_with_nodes(xy: np.ndarray, node: np.ndarray, front: np.ndarray, estimate: np.ndarray) -> np.ndarray:
    """Points (K, 2) each moved as its node `node` (K,) moved: from its front-end pose to its estimate."""
    return transform_points(compose(estimate[node], inverse(front[node])), xy)


def correct_between(
    front: np.ndarray,
    node_steps: np.ndarray,
    node_front: np.ndarray,
    node_est: np.ndarray,
    at_steps: np.ndarray | None = None,
) -> np.ndarray:
    """`front` (T, 3) corrected by the nodes: scan t's pose relative to its nodes kept, blended. `at_steps`:
    the steps of `front`'s rows (default 0 to T - 1)."""
    t = np.arange(len(front)) if at_steps is None else np.asarray(at_steps)
    if len(node_steps) == 0:
        return front.copy()
    before = np.clip(np.searchsorted(node_steps, t, side="right") - 1, 0, len(node_steps) - 1)
    after = np.clip(before + 1, 0, len(node_steps) - 1)
    via_a = compose(node_est[before], compose(inverse(node_front[before]), front))
    via_b = compose(node_est[after], compose(inverse(node_front[after]), front))
    span = (node_steps[after] - node_steps[before]).astype(float)
    f = np.where(span > 0, (t - node_steps[before]) / np.where(span > 0, span, 1.0), 0.0)
    return interpolate(via_a, via_b, np.clip(f, 0.0, 1.0))
