"""Filter configuration: every open point of the paper is a named option (docs/CHOICES.md)."""

from __future__ import annotations

import math
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
    """G-SLAM options, with defaults chosen by measurement on the Car Park log (docs/CHOICES.md).

    Paper-literal settings: observation_unit "scan", map_update "global", prune_relative False,
    weighting "sum", proposal "motion", update_schedule "every_scan" (see `literal()`).
    """

    particles: int = 8
    """N, the number of particles."""
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

    # Sensor noise (R) and the point likelihood q (eq. 6; open point 2).
    range_sigma_m: float = 0.02
    """Range noise of the laser (sd of the draw of new points, R). 0.10 m smears every surface along the
    beams and the scan matcher then drifts (docs/CHOICES.md)."""
    bearing_sigma_rad: float = math.radians(0.25)
    """Bearing noise of the laser (sd of the draw of new points, R)."""
    hit_sigma_m: float = 0.20
    """Width of the range term of q for existing points (pose uncertainty included)."""
    hit_ratio: float = 3.0
    """q of a point at a return, relative to an unobserved point (q = 1)."""
    free_ratio: float = 0.9
    """q of a point in observed free space (in front of the return), relative to an unobserved point.
    Points seen as free about 8 times in a row fall below the pruning threshold; a stronger ratio (0.3)
    also erases surfaces seen at grazing angles or with a small pose error, and the matcher suffers."""
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
    max_points_per_cell: int = 2
    """Density control: keep at most this many points (the most probable) per cell; 0 = off."""
    cell_size_m: float = 0.25
    """Cell size of the density control."""

    # Open point 4: the importance weight.
    weighting: Weighting = "matched_field"
    """"sum": w = sum_j q_j p_j (literal); "beam_sum": product over returns of the per-beam sum;
    "likelihood_field": product over returns of the best-matching map point's Gaussian score;
    "matched_field": the scan's log-likelihood at the matched pose from the scan matcher's field
    (sum over returns of -d^2 / 2 weight_sigma_m^2, d capped at weight_miss_m), divided by
    weight_gain x N, as GMapping weighs its particles (`gslam.fieldmatch`)."""
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
    weight_beam_stride: int = 2
    """Use every k-th return in the weight and the scan matcher."""

    # Open point 5: prior of new points.
    prior_interpolation: PriorInterpolation = "cell_mean"
    """"cell_mean": mean p of the particle's points in the same cell (cell_size_m); "nearest_mean": mean
    p of the k nearest points within prior_radius_m; "idw": inverse distance weighting of those;
    "constant": always p0."""
    prior_neighbours: int = 4
    prior_radius_m: float = 0.5
    prior_p0: float = 0.5
    """Prior where no point lies within the radius: a probability for "binary", else x mean p."""

    # Open point 6: proposal.
    proposal: Proposal = "scan_match"
    """"motion": sample the motion model (the paper); "scan_match": sample the motion model, then refine
    each particle's pose by hill climbing a likelihood field of the scan over the particle's own point
    map (GMapping's scan matcher, on points instead of a grid), then sample around the match."""
    match_sigma_m: float = 0.158
    """Distance scale of the matcher's score exp(-d^2 / 2 sigma^2) (GMapping: exp(-d^2 / 0.05))."""
    match_cell_m: float = 0.05
    """Cell of the raster the matcher builds from each particle's map points near the scan; a cell
    keeps the mean of its points (GMapping's map resolution, delta 0.05 m)."""
    match_kernel: int = 1
    """Cells searched either side of an end point's cell for the nearest occupied cell."""
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
    match_window_margin_m: float = 1.0
    """The matcher rasterises the map points inside the box of the scan's end points (at the motion
    sample) grown by this margin: work local to the scan, whatever the size of the map."""
    match_min_score: float = 0.0
    """A match counts when its score exceeds this fraction of the returns used; otherwise the
    particle keeps its motion-model sample (GMapping minimumScore 0)."""
    proposal_sigma_xy_m: float = 0.01
    proposal_sigma_phi_rad: float = math.radians(0.1)

    # Open point 7: when to update.
    update_schedule: UpdateSchedule = "travel"
    """"every_scan" (the paper) or "travel": only after min_travel_m or min_turn_rad since the last update."""
    min_travel_m: float = 1.0
    min_turn_rad: float = 0.5
    fill_skipped: FillSkipped = "odometry"
    """Poses recorded for the scans the travel schedule skips: "odometry", each particle's last updated
    pose moved by the noise-free motion (as GMapping fills them); "sampled", the motion-model samples
    the filter carries (their noise is only there to be weighed at the next update)."""

    # Resampling.
    resample_threshold: float = 0.5
    """Resample (RSR) when the effective sample size falls below this fraction of N."""

    # Motion noise.
    control_noise: ControlNoise = "per_interval"
    """"per_sample": fresh noise at every odometry sample; "per_interval": one draw per scan interval."""
    speed_sigma_mps: float = 0.10
    speed_sigma_rel: float = 0.05
    steering_sigma_rad: float = math.radians(1.0)
    odom_sigma: tuple[float, float, float, float] = (0.1, 0.2, 0.1, 0.2)
    """Odometry motion noise (srr, srt, str, stt), in the robot frame (`motion.apply_odometry`): sd of
    translation per metre and per radian, sd of rotation per metre and per radian (GMapping's defaults)."""
    initial_sigma_xy_m: float = 0.0
    initial_sigma_phi_rad: float = 0.0

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        if not 1 <= self.particles <= 4096:
            raise ValueError(f"particles must be between 1 and 4096, got {self.particles}")
        if self.points_per_observation < 1:
            raise ValueError(f"points per observation must be at least 1, got {self.points_per_observation}")
        choices = {
            "observation_unit": ("beam", "scan"),
            "map_update": ("global", "observed", "binary"),
            "weighting": ("sum", "beam_sum", "likelihood_field", "matched_field"),
            "prior_interpolation": ("cell_mean", "nearest_mean", "idw", "constant"),
            "proposal": ("motion", "scan_match"),
            "update_schedule": ("every_scan", "travel"),
            "control_noise": ("per_sample", "per_interval"),
            "fill_skipped": ("odometry", "sampled"),
        }
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {', '.join(allowed)}, got {getattr(self, name)!r}")
        if self.match_levels < 1 or self.match_max_iterations < 1 or self.match_kernel < 0:
            raise ValueError("match_levels and match_max_iterations must be at least 1, match_kernel at least 0")
        if not 0 < self.resample_threshold <= 1:
            raise ValueError("resample_threshold must be in (0, 1]")
        for name in (
            "range_sigma_m",
            "hit_sigma_m",
            "weight_sigma_m",
            "cell_size_m",
            "prior_radius_m",
            "match_sigma_m",
            "match_step_xy_m",
            "match_step_phi_rad",
            "match_cell_m",
            "weight_miss_m",
            "weight_gain",
        ):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive")

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
