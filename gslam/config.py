"""Filter configuration: every open point of the paper is a named option (docs/CHOICES.md)."""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

ObservationUnit = Literal["beam", "scan"]
MapUpdate = Literal["global", "observed", "binary"]
Weighting = Literal["sum", "beam_sum", "likelihood_field", "matched_field"]
PriorInterpolation = Literal["cell_mean", "nearest_mean", "idw", "constant"]
Proposal = Literal["motion", "scan_match"]
UpdateSchedule = Literal["every_scan", "travel"]
ControlNoise = Literal["per_sample", "per_interval"]
FillSkipped = Literal["odometry", "sampled"]


@dataclass
class FilterConfig:
    """G-SLAM options, with defaults chosen by measurement on every log of the corpus (docs/CHOICES.md).

    Paper-literal settings: observation_unit "scan", map_update "global", prune_relative False,
    weighting "sum", proposal "motion", update_schedule "every_scan" (see `literal()`).
    """

    particles: int = 30
    """N, the number of particles. 30, GMapping's default: at the paper's 8 the filter breaks loops on
    logs it holds at 30 (docs/CHOICES.md, "The number of particles"); `-N 8` gives the paper's."""
    points_per_observation: int = 10
    """M, new map points drawn per observation (per return, or per scan: see observation_unit)."""
    seed: int = 0
    """Seed of the numpy Generator behind every random draw."""

    # Open point 1: what an "observation" is.
    observation_unit: ObservationUnit = "beam"
    """"beam": M points around every return; "scan": M points per scan, each around a random return."""

    min_range_m: float | None = None
    """Returns closer than this are ignored as observations (they still occlude). None: the input's own
    self-return range (1.0 m on the Sydney logs, whose laser sees the car at 0.84-0.92 m on beams 0-7
    in every Car Park scan; 0 elsewhere)."""

    usable_range_m: float | None = None
    """Returns farther than this are not observations (no new points, left out of the weight and the scan
    matcher) and their beams clear free space only up to it, as GMapping's maxUrange treats them: for a
    laser whose far readings are too noisy or too sparse to map. None: the laser's own maximum range."""

    # Sensor noise (R) and the point likelihood q (eq. 6; open point 2).
    range_sigma_m: float = 0.005
    """Range noise of the draw of new points (sd, R). The return already carries the laser's own noise (1 to
    2 cm); the draw adds its spread to every point the matcher reads, so a narrow one keeps surfaces sharp:
    0.02 m left the corpus logs' relations 5 to 20 % worse, 0.10 m smears surfaces and the matcher drifts
    (docs/CHOICES.md)."""
    bearing_sigma_rad: float = math.radians(0.1)
    """Bearing noise of the laser (sd of the draw of new points, R). A beam's direction is known to the
    encoder's precision; a wide draw puts new points beside the surface wherever the beam meets it at an
    angle (docs/CHOICES.md)."""
    hit_sigma_m: float = 0.20
    """Width of the range term of q for existing points (pose uncertainty included)."""
    hit_ratio: float = 3.0
    """q of a point at a return, relative to an unobserved point (q = 1)."""
    free_ratio: float = 0.9
    """q of a point in observed free space (in front of the return), relative to an unobserved point.
    Points seen as free about 8 times in a row fall below the pruning threshold; a stronger ratio (0.3)
    also erases surfaces seen at grazing angles or with a small pose error, and the matcher suffers."""
    no_return_free_m: float | None = None
    """How far a beam without a return (nothing within the sensor's range) observes free space: None, all
    the way to the maximum range; a length, up to it (Cartographer's missing_data_ray_length; 0: none, as
    GMapping skips such beams). A thin or dark obstacle the beam passes beside, or an absorbing surface,
    also gives no return (docs/CHOICES.md, "Beams without a return")."""
    free_space_beams: int = 0
    """A point is in observed free space only when it lies in front of the returns of its beam and of
    this many beams either side (0: its own beam only). Guards surfaces seen at grazing angles, where
    the nearest beam's return lies further along the surface, from being erased."""

    # Open point 3: the semantic of p and the pruning threshold.
    map_update: MapUpdate = "binary"
    """"global": eq. 7 over all the particle's points (literal); "observed": eq. 7 over the points this
    scan observes, so unobserved points keep their p; "binary": per-point Bayes in log-odds."""
    prune_threshold: float = 0.3
    """p_thr: a probability for the binary map; with prune_relative, a fraction of the mean p."""
    prune_relative: bool = False
    """Compare p with prune_threshold x mean p (True) or with prune_threshold itself (literal)."""
    max_points_per_cell: int = 1
    """Density control: keep at most this many points (the most probable) per cell; 0 = off."""
    cell_size_m: float = 0.1
    """Cell size of the density control (and of the cell-mean prior). 0.1 m keeps about ten points per
    metre of wall, dense enough for the matcher to find a point near every return (docs/CHOICES.md)."""

    # Open point 4: the importance weight.
    weighting: Weighting = "matched_field"
    """"sum": w = sum_j q_j p_j (literal); "beam_sum": product over returns of the per-beam sum;
    "likelihood_field": product over returns of the best-matching map point's Gaussian score;
    "matched_field": the scan's log-likelihood at the matched pose from the scan matcher's field
    (sum over returns of -d^2 / 2 weight_sigma_m^2, d capped at weight_miss_m), divided by
    weight_gain x N, as GMapping weighs its particles (`gslam.scanmatch`)."""
    weight_sigma_m: float = 0.20
    """Distance scale of the likelihood-field, beam-sum and matched-field weights."""
    weight_floor: float = 0.05
    """Per-return likelihood floor (outliers, unmapped space) of beam_sum and likelihood_field."""
    weight_tempering: float = 0.3
    """Exponent on the product over returns of beam_sum and likelihood_field (returns are not independent)."""
    weight_miss_m: float = 0.7
    """matched_field: a return with no occupied cell near its end point counts as this far off
    (GMapping's null likelihood -0.5 / 0.075 with sigma 0.2 m)."""
    weight_gain: float = 3.0
    """matched_field: the log-likelihood is divided by weight_gain x N before it multiplies the weight
    (GMapping's observation gain, ogain = 3): returns are far from independent, and the division
    keeps the effective sample size from collapsing at every update."""
    weight_beam_stride: int = 1
    """Use every k-th return in the weight and the scan matcher's score (1: every return, as GMapping). The
    matcher's climb thins them further (match_climb_stride); its Gauss-Newton finish uses them all."""

    # Open point 5: prior of new points.
    prior_interpolation: PriorInterpolation = "cell_mean"
    """"cell_mean": mean p of the particle's points in the same cell (cell_size_m); "nearest_mean": mean
    p of the k nearest points within prior_radius_m; "idw": inverse distance weighting of those;
    "constant": always p0."""
    prior_neighbours: int = 4
    """k, the nearest points that "nearest_mean" and "idw" interpolate."""
    prior_radius_m: float = 0.5
    """Radius [m] within which "nearest_mean" and "idw" look for those points."""
    prior_p0: float = 0.5
    """Prior where no point lies within the radius: a probability for "binary", else x mean p."""

    # Open point 6: proposal.
    proposal: Proposal = "scan_match"
    """"motion": sample the motion model (the paper); "scan_match": sample the motion model, then refine
    each particle's pose by hill climbing a likelihood field of the scan over the particle's own point
    map (GMapping's scan matcher, on points instead of a grid), then sample around the match."""
    match_sigma_m: float = 0.05
    """Distance scale of the matcher's score exp(-d^2 / 2 sigma^2). GMapping's exp(-d^2 / 0.05) is sigma
    0.158 m over a 1-cell search of a grid whose cells keep the mean of many hits."""
    match_sigma_rad: float | None = 0.0
    """Angular part of the score's width for a return scored point to point (no line found, see
    match_line_pair_m): sigma^2 = match_sigma_m^2 + (r match_sigma_rad)^2, the spacing of the map's
    points along a surface seen at range r. None: the sensor's angle between beams (from the input).
    0 (default): one width for every return (the sensor's angle measured worse, docs/CHOICES.md)."""
    match_cell_m: float = 0.05
    """Cell of the raster the matcher builds from each particle's map points near the scan; a cell
    keeps the mean of its points (GMapping's map resolution, delta 0.05 m)."""
    match_kernel: int = 1
    """Cells searched either side of an end point's cell for the map (GMapping's kernelSize 1: within
    0.05 to 0.1 m). Point-to-point distances needed 2 cells (the spacing of the map's points) to close
    loops; with point-to-line distances 1 cell holds them, at less cost (docs/CHOICES.md)."""
    match_line_pair_m: float = 0.2
    """Point to line: when the two nearest cell means found for a return lie at most this far apart
    (neighbouring samples of one surface: twice the map's point spacing, cell_size_m), the return's
    distance is taken across the line through them instead of to the nearest of them (PL-ICP, Censi
    2008), so it does not depend on where the return falls between the map's samples. 0: point to point
    everywhere."""
    match_coarse_factor: int = 4
    """A second start for the matcher, coarse to fine: besides the fine climb from the motion sample, a climb
    on a raster this many times coarser than match_cell_m (the score's width, the kernel's reach, the
    steps and the line pairs scaled alike), then on the fine raster
    from where it stopped (as multi-resolution matchers do: Olson 2009, Hector, Cartographer). Its returns
    find the map up to this many times further away, so an odometry error of a few tenths of a metre (a
    slip, a sign error when reversing) is still inside its basin. It is climbed on the fine raster only
    when it ends more than a coarse cell or factor / 2 angular steps from the fine result, and replaces
    that only by a clear margin (match_coarse_min_gain). 1: the fine climb only (docs/CHOICES.md)."""
    match_coarse_levels: int = 2
    """Step halvings of the coarse climb (log2 of match_coarse_factor brings its steps to the fine ones)."""
    match_coarse_depth: int = 1
    """Levels of the coarse start's pyramid, each match_coarse_factor times coarser than the one below: the
    climb starts on the coarsest from the motion sample and descends (1: one level, 0.2 m cells)."""
    match_coarse_deeper_travel_m: float = 3.0
    """Where the noise-free travel since the last update reaches this, the coarse start's pyramid has one
    level more than match_coarse_depth (0.8 m cells): the error the odometry carries grows with the motion
    (a slip reports 1.2 to 2x), and beyond about a metre of error a scan is out of the 0.2 m raster's basin
    along a corridor. Updates come every min_travel_m, so only logs whose scans lie metres apart reach it;
    at 2 m the deeper raster took look-alikes at the Freiburg campus's slips (docs/CHOICES.md). 0: never."""
    match_coarse_stride: int = 1
    """The coarse climb uses every k-th of the climb's returns (1: all of them). Every 2nd was cheaper by
    little and broke a loop on the Freiburg campus (docs/CHOICES.md)."""
    match_coarse_min_gain: float = 0.05
    """The coarse start's match replaces the fine climb's only when its score is higher by this fraction of
    the returns. Where a scan has few returns (68 at the Car Park's first updates), two poses half a metre
    apart along the track can score alike, and a jump against the odometry must be paid for by returns it
    explains; the slips the coarse start recovers on belgioioso gain a median of 42 % (docs/CHOICES.md)."""
    match_coarse_gate: float = 0.9
    """The coarse start is tried only for the particles whose fine match fits at most this fraction as well
    as the reference: the best fine match among the particles, or the median of the previous update's
    matches if that is higher (so a slip that takes every particle out of the fine climb's basin is caught
    too); the fit of a match is its score per return. A particle whose fine climb found the map as well as
    the others did has nothing to recover, and the coarse climb then costs about 40 % of the fine one
    (score evaluations on mit-csail) for nothing: on the corpus the gate at 0.9 keeps 97 to 100 % of the
    matches the coarse start improves while trying it on 9 to 66 % of the particles (docs/CHOICES.md).
    Above 1: every particle."""
    match_min_p: float = 0.5
    """Map points with at least this probability take part in matching and weighing."""
    match_step_xy_m: float = 0.05
    """First hill-climbing step in x and y (halved at each level; GMapping lstep)."""
    match_step_phi_rad: float = 0.05
    """First hill-climbing step in heading (halved at each level; GMapping astep)."""
    match_levels: int = 5
    """Step halvings before the climb stops (GMapping iterations)."""
    match_max_iterations: int = 100
    """Cap on hill-climbing iterations (each tries 6 moves)."""
    match_climb_stride: int = 2
    """The climb scores every k-th of the matcher's returns: enough to find the basin and walk the lattice of
    poses; the Gauss-Newton finish (match_polish_iterations), the score it reports and the weight use every
    return. On the corpus the finish on all returns after a climb on every second one was as accurate as
    the climb on all of them, at the cost of the climb on half (docs/CHOICES.md). 1: the climb on all."""
    match_fine_stride: int = 1
    """k > 1: the climb's last `match_fine_levels` step sizes (its finest: 6, 3 and 1.6 mm with the default
    steps) score every k-th of the climb's returns, the larger steps, which find the basin, keeping them
    all; the Gauss-Newton finish on every return follows. 2 makes the matcher 11 % cheaper and measured
    within the seeds' spread on six logs of the corpus, but the campus was worse over ten seeds (0.296 m
    mean, worst 0.569, against 0.250 and 0.430; docs/CHOICES.md), so it is not the default. 1: the
    whole climb on the climb's returns."""
    match_fine_levels: int = 3
    """How many of the climb's `match_levels` + 1 step sizes, the finest, `match_fine_stride` applies to."""
    match_polish_iterations: int = 5
    """After the climb's `match_levels` step halvings, at most this many Gauss-Newton steps on the score over
    all the returns (`gslam.scanmatch._finish`: iteratively reweighted least squares on the point-to-line
    and point-to-point residuals, a step kept only if the score rises): a continuous refinement of the
    climb's lattice pose with every return. 0: none."""
    match_window_margin_m: float = 1.0
    """The matcher rasterises the map points inside the box of the scan's end points (at the motion
    sample) grown by this margin: work local to the scan, whatever the size of the map."""
    match_min_score: float = 0.0
    """A match counts when its score exceeds this fraction of the returns used; otherwise the
    particle keeps its motion-model sample (GMapping minimumScore 0)."""
    proposal_sigma_xy_m: float = 0.0
    """Gaussian position noise [m, sd] added to a matched pose (0: none, see proposal_sigma_phi_rad)."""
    proposal_sigma_phi_rad: float = 0.0
    """Gaussian noise added to a matched pose (sampling around the match). 0: the particle takes the
    matched pose, as GMapping's implementation does; the particles differ by their motion samples."""

    # Open point 7: when to update.
    update_schedule: UpdateSchedule = "travel"
    """"every_scan" (the paper) or "travel": only after min_travel_m or min_turn_rad since the last update."""
    min_travel_m: float = 0.5
    """Travel between updates. G-SLAM estimates a surface from the points it draws around the returns of
    the scans it integrates (one kept per cell), so it gains more from integrating scans more often
    than a grid whose cells average every hit: half GMapping's 1 m (docs/CHOICES.md)."""
    min_turn_rad: float = 0.5
    """Turn between updates (GMapping's angularUpdate)."""
    recheck_ratio: float = 0.5
    """An update whose match moves the particles (their median) further from the noise-free motion since the
    last update than recheck_ratio x that motion + recheck_travel_m (in travel; in turn, x the turn +
    recheck_turn_rad) says the motion went wrong there (a slip, odometry that counts a reversal forward):
    the next update then comes after recheck_travel_m or recheck_turn_rad instead, and so on until a match
    agrees with the motion again. Where the odometry holds nothing changes. 0: off (docs/CHOICES.md)."""
    recheck_travel_m: float = 0.1
    """Travel between updates while the motion is rechecked (recheck_ratio)."""
    recheck_turn_rad: float = 0.1
    """Turn between updates while the motion is rechecked (recheck_ratio)."""
    fill_skipped: FillSkipped = "odometry"
    """Poses recorded for the scans the travel schedule skips: "odometry", each particle's last updated
    pose moved by the noise-free motion (as GMapping fills them); "sampled", the motion-model samples
    the filter carries (their noise is only there to be weighed at the next update)."""

    # Every scan placed by the final map (gslam.placement).
    place_every_scan: bool = True
    """When the run ends, match every scan of the best particle's trajectory against its final map (from
    its recorded pose, or the scan before it as placed moved by the recorded motion), so that no scan's
    pose is the odometry's between updates; a scan whose match is not kept is placed between its matched
    neighbours. False: the trajectory as the filter recorded it (docs/CHOICES.md)."""
    place_step_xy_m: float = 0.01
    """The placement's first climb step in x and y: its start is within the odometry's error over one
    scan of the answer, so it climbs in finer steps than the update's matcher (match_step_xy_m)."""
    place_step_phi_rad: float = 0.01
    """The placement's first climb step in heading."""
    place_levels: int = 2
    """Step halvings of the placement's climb (then match_polish_iterations Gauss-Newton steps)."""
    place_climb_stride: int = 1
    """The placement's climb scores every k-th return (1: all of them; the update's matcher takes every
    match_climb_stride-th): one match a scan, so every return is worth its time (docs/CHOICES.md)."""
    place_rasters: int = 2
    """The map is rasterised for the placement this many times, each raster's cell lattice shifted over
    the cell (`gslam.placement.raster_shifts`); a scan climbs on the first and is finished by Gauss-Newton on
    each of the others from there, and is placed at the mean of the matches. A raster summarises its
    points by their cell's mean, so a match moves by millimetres with where the cell edges fall; the mean
    of two rasters' matches errs less (docs/CHOICES.md)."""
    place_min_hit_fraction: float = 0.5
    """A placement match is kept when at least this share of the scan's returns find the map near them."""
    place_max_shift_m: float = 0.5
    """... and it moves the scan's start by less than this (more is a jump, not a correction) ..."""
    place_max_turn_rad: float = 0.25
    """... and turns it by less than this."""
    place_retrack: bool = True
    """Place each update's scan a second time from the pose tracked to it (the scan before as placed, moved
    by the odometry), with the scans after it up to the next update, and keep the chain that fits the final
    map better (`gslam.placement.Retrack`): a jump the filter took at an update, which the scans after it
    do not bear out, is undone (docs/CHOICES.md)."""
    place_retrack_m: float = 0.02
    """... where the tracked start lies at least this far from the recorded one ..."""
    place_retrack_rad: float = 0.01
    """... or turned at least this much from it."""
    loop_closure: bool = True
    """When the run ends (after the placement), put a pose graph under the trajectory: nodes every 0.5 m or
    0.5 rad, tied by the placed motion, closed by each node's scan found by branch and bound in submaps
    left at least 20 m of travel before, optimised under a robust loss (`gslam.backend`, its settings
    `BackEndSettings`); the trajectory, the final map and the occupancy grid follow the optimised graph.
    False: the placed trajectory as it is (docs/CHOICES.md, "Back end")."""
    loop_closure_live: bool = True
    """With loop_closure, also build the graph while the run goes, in a background thread, from the best
    particle's poses (`gslam.livebackend`): from the moment it accepts closures that the front end misses,
    /tf's map -> odom, the pose, the particles, the path and the map snapshots follow it. Its timing depends
    on the machine; the final trajectory and map do not (the run's end builds the graph again)."""

    # Resampling.
    resample_threshold: float = 0.5
    """Resample (RSR) when the effective sample size falls below this fraction of N."""

    # Motion noise.
    control_noise: ControlNoise = "per_interval"
    """"per_sample": fresh noise at every odometry sample; "per_interval": one draw per scan interval."""
    speed_sigma_mps: float = 0.10
    """Ackermann logs: speed noise [m/s, sd], the constant part."""
    speed_sigma_rel: float = 0.05
    """Ackermann logs: speed noise, the part proportional to the speed (sd per m/s)."""
    steering_sigma_rad: float = math.radians(1.0)
    """Ackermann logs: steering angle noise [rad, sd]."""
    odom_sigma: tuple[float, float, float, float] = (0.1, 0.2, 0.1, 0.2)
    """Odometry motion noise (srr, srt, str, stt), in the robot frame (`motion.apply_odometry`): sd of
    translation per metre and per radian, sd of rotation per metre and per radian (GMapping's defaults)."""
    motion_noise_adaptive: bool = True
    """Learn how good the odometry's heading is from the scan matches and narrow the motion model's
    heading noise to it (`GSlamFilter._adapt_heading_noise`): the model's defaults (GMapping's) are an
    upper bound, wide enough for a poor robot; sampling a good robot's heading that widely sends
    particles into rotated alignments of the scan (aliasing) that a narrower spread does not reach.
    Translation noise is left as the model gives it: along a corridor the matches cannot see it."""
    motion_noise_window: int = 20
    """Updates over which the heading error is averaged (a running mean with weight 1 / window)."""
    motion_noise_safety: float = 3.0
    """The heading noise is this many times the heading error the matches found (as sd)."""
    motion_noise_min_scale: float = 0.2
    """The least factor on the model's heading noise."""
    motion_noise_clip: float = 3.0
    """Robust update of the learnt heading error: one update's squared error ratio enters the running mean
    at most this squared times the mean (held no lower than the floor's level, (min_scale / safety)^2), as
    a Huber-type estimator does, so that a single slip (an outlier the matcher corrects) does not reopen
    the model for the next ~3 x `window` updates (70 on the campus), while errors that stay large still
    grow the estimate by up to (1 + (clip^2 - 1) / window) per update (floor to full model in about 10
    updates). 0: off (the plain running mean of squares)."""
    continue_max_p: float = 0.57
    """A map continued from an earlier run (`gslam process --continue`, `GSlamFilter.seed_map`) comes in
    with every point's p capped at this: still matched (at or above `match_min_p`), but no longer sure. A
    place this run sees again is then mapped from this run's own returns: a point drawn at a return takes
    its cell's p as its prior and gains the hit, so it outscores the old point in the cell at the first
    sighting, while a saved point held at 1 - 1e-6 would never be outscored; and free space seen three
    times takes an old point below matching. The earlier map carries its run's own pose errors, which the
    new run would otherwise inherit where it revisits (docs/CHOICES.md, "Maps that go on"). A point the
    run leaves as it was is saved again at its own p (`GSlamFilter.restore_saved_p`). 1: p as saved."""
    initial_sigma_xy_m: float = 0.0
    """Spread [m, sd] of the particles' initial positions (0: all start at the origin or the GPS fit)."""
    initial_sigma_phi_rad: float = 0.0
    """Spread [rad, sd] of the particles' initial headings."""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check every field against its annotated type (int, float, bool, a Literal's choices, an
        optional or a fixed-length tuple) and its range (`_LIMITS`; numbers without an entry must be
        finite and non-negative). A bad value raises ValueError naming the option, what was expected
        and what was given. New fields are checked by their annotation without further code."""
        check_fields(self, _LIMITS)
        if self.map_update == "binary" and not 0 < self.prior_p0 < 1:
            raise ValueError(f"prior_p0 must be a probability in (0, 1) with map_update binary, got {self.prior_p0!r}")

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["odom_sigma"] = list(self.odom_sigma)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FilterConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown filter option(s): {', '.join(unknown)}")
        data = dict(data)
        if "odom_sigma" in data:
            data["odom_sigma"] = tuple(data["odom_sigma"])
        return cls(**data)

    @classmethod
    def literal(cls, **overrides: Any) -> FilterConfig:
        """The paper-literal reading of every open point."""
        base = dict(
            observation_unit="scan",
            map_update="global",
            prune_relative=False,
            prune_threshold=1e-6,
            max_points_per_cell=0,
            weighting="sum",
            proposal="motion",
            update_schedule="every_scan",
            prior_interpolation="idw",
            free_ratio=0.01,
        )
        base.update(overrides)
        return cls(**base)


# Ranges of numeric options: (low, high, low inclusive). Numbers not listed must be >= 0; every number
# must be finite. Upper bounds keep the arrays the filter allocates to a size a machine holds, and keep
# lengths, angles and noise within what any laser or robot could mean (a 1e300 m cell is accepted by
# "finite and positive", and gives an empty map, or an overflow in the cell keys, only after the first scan).
_METRES = 1_000
"""The bound of a length or a length's noise [m]: beyond any laser's range."""
_CELL_M = 100
"""The bound of a cell or a search window [m]: one cell would hold a whole map."""
_RADIANS = 10
"""The bound of an angle or an angle's noise [rad]: beyond a full turn, more means nothing more."""
_LIMITS: dict[str, tuple[float, float, bool]] = {
    "particles": (1, 4096, True),
    "points_per_observation": (1, 1000, True),
    "seed": (0, 2**32 - 1, True),
    "min_range_m": (0, _METRES, True),
    "usable_range_m": (0, _METRES, False),
    "range_sigma_m": (0, _METRES, False),
    "bearing_sigma_rad": (0, _RADIANS, True),
    "hit_sigma_m": (0, _METRES, False),
    "hit_ratio": (0, math.inf, False),
    "free_ratio": (0, math.inf, False),
    "free_space_beams": (0, 1000, True),
    "no_return_free_m": (0, _METRES, True),
    "max_points_per_cell": (0, 1000, True),
    "cell_size_m": (0.01, _CELL_M, True),
    "weight_sigma_m": (0, _METRES, False),
    "weight_floor": (0, 1, False),
    "weight_beam_stride": (1, 10_000, True),
    "match_coarse_factor": (1, 64, True),
    "match_coarse_levels": (0, 64, True),
    "match_coarse_stride": (1, 10_000, True),
    "match_coarse_gate": (0, 64, True),
    "match_coarse_depth": (1, 4, True),
    "match_coarse_deeper_travel_m": (0, _METRES, True),
    "prior_neighbours": (1, 64, True),
    "prior_radius_m": (0, _CELL_M, False),
    "prior_p0": (0, math.inf, False),
    "match_sigma_m": (0, _METRES, False),
    "match_step_xy_m": (0, _CELL_M, False),
    "match_step_phi_rad": (0, _RADIANS, False),
    "match_levels": (1, 30, True),
    "match_kernel": (0, 20, True),
    "match_sigma_rad": (0, 1, True),
    "match_cell_m": (0.005, _CELL_M, True),
    "match_line_pair_m": (0, _CELL_M, True),
    "match_window_margin_m": (0, _CELL_M, True),
    "match_min_p": (0, 1, True),
    "continue_max_p": (0, 1, False),
    "weight_miss_m": (0, _METRES, False),
    "weight_gain": (0, math.inf, False),
    "match_max_iterations": (1, 10_000, True),
    "match_polish_iterations": (0, 1_000, True),
    "match_climb_stride": (1, 10_000, True),
    "match_fine_stride": (1, 10_000, True),
    "match_fine_levels": (0, 64, True),
    "match_min_score": (0, 1, True),
    "proposal_sigma_xy_m": (0, _METRES, True),
    "proposal_sigma_phi_rad": (0, _RADIANS, True),
    "min_travel_m": (0, _METRES, True),
    "min_turn_rad": (0, _RADIANS, True),
    "recheck_ratio": (0, 1_000, True),
    "recheck_travel_m": (0, _METRES, True),
    "recheck_turn_rad": (0, _RADIANS, True),
    "place_step_xy_m": (0, _CELL_M, False),
    "place_step_phi_rad": (0, _RADIANS, False),
    "place_levels": (0, 30, True),
    "place_climb_stride": (1, 10_000, True),
    "place_rasters": (1, 64, True),
    "place_min_hit_fraction": (0, 1, True),
    "place_max_shift_m": (0, _METRES, False),
    "place_max_turn_rad": (0, _RADIANS, False),
    "place_retrack_m": (0, _METRES, True),
    "place_retrack_rad": (0, _RADIANS, True),
    "resample_threshold": (0, 1, False),
    "speed_sigma_mps": (0, _METRES, True),
    "speed_sigma_rel": (0, _METRES, True),
    "steering_sigma_rad": (0, _RADIANS, True),
    "odom_sigma": (0, _METRES, True),
    "motion_noise_window": (1, 1_000_000, True),
    "motion_noise_min_scale": (0, 1, True),
    "motion_noise_safety": (0, math.inf, False),
    "initial_sigma_xy_m": (0, _METRES, True),
    "initial_sigma_phi_rad": (0, _RADIANS, True),
}


def check_fields(obj: Any, limits: dict[str, tuple[float, float, bool]], skip: tuple[str, ...] = ()) -> None:
    """Check every field of the dataclass `obj` (but `skip`) by its annotated type and `limits`."""
    import typing

    hints = typing.get_type_hints(type(obj))
    for f in fields(obj):
        if f.name not in skip:
            check_value(f.name, hints[f.name], getattr(obj, f.name), limits)


def _type_name(tp: Any) -> str:
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string"}.get(tp, str(tp))


def check_value(name: str, tp: Any, value: Any, limits: dict[str, tuple[float, float, bool]]) -> None:
    """Raise ValueError unless `value` fits the annotation `tp` and the range of option `name` in
    `limits` (numbers without an entry: finite and >= 0)."""
    import types
    import typing

    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        if value not in args or isinstance(value, bool):
            raise ValueError(f"{name} must be one of {', '.join(map(str, args))}, got {value!r}")
        return
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return
        (inner,) = [a for a in args if a is not type(None)]
        check_value(name, inner, value, limits)
        return
    if origin is tuple:
        if not isinstance(value, list | tuple) or len(value) != len(args):
            raise ValueError(f"{name} must be a list of {len(args)} numbers, got {value!r}")
        for i, (a, v) in enumerate(zip(args, value, strict=True)):
            check_value(f"{name}[{i}]", a, v, limits)
        return
    if tp is str:
        if not isinstance(value, str):
            raise ValueError(f"{name} must be a string, got {value!r}")
        return
    if tp is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false, got {value!r}")
        return
    if tp in (int, float):
        ok = isinstance(value, numbers.Integral) if tp is int else isinstance(value, numbers.Real)
        if not ok or isinstance(value, bool):
            raise ValueError(f"{name} must be {_type_name(tp)}, got {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value!r}")
        lo, hi, lo_inclusive = limits.get(name.split("[")[0], (0, math.inf, True))
        if value < lo or (value == lo and not lo_inclusive) or value > hi:
            if hi == math.inf:
                wanted = f"{'>=' if lo_inclusive else '>'} {lo:g}"
            else:
                wanted = f"in {'[' if lo_inclusive else '('}{lo:g}, {hi}]"
            raise ValueError(f"{name} must be {wanted}, got {value!r}")
        return
    if isinstance(tp, type) and not isinstance(value, tp):  # other kinds of field: their class at least
        raise ValueError(f"{name} must be a {tp.__name__}, got {value!r}")
