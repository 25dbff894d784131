"""The Rerun recording's entity paths and timelines, in one place (as `mcaplog.channels` is for the MCAP
topics): the child writer logs to them, the blueprint shows them, the tests read them."""

SCAN_TIMELINE = "scan"
"""Sequence timeline: the scan's index in the log."""
TIME_TIMELINE = "time"
"""Duration timeline: seconds since the log's start."""

WORLD = "world"
"""Everything below is in the map frame (x east or ahead, y north or left). The map view's origin is the
root, and `world` carries a static mirror of y (`Transform3D(scale=(1, -1, 1))`): Rerun's 2-D views have y
down, so without it every map would be drawn upside down against the plots."""
MAP = "world/map"
"""The best particle's map points, coloured by probability (snapshots, and the final map)."""
SCAN = "world/scan"
"""The end points of the scan's returns, from the best particle's laser pose (one row per step)."""
PARTICLES = "world/particles"
"""The particles' positions (one row per step)."""
GPS = "world/gps"
"""The GPS track (static), where the log has one."""
LANDMARKS = "world/landmarks"
"""Surveyed poles or simulated landmarks (static), where the log has them."""
LANDMARK_ELLIPSES = "world/landmark_ellipses"
"""FastSLAM: the 3-sigma ellipses of the best particle's landmarks (final)."""
ROBOT = "world/robot"
"""The best particle's pose at each step: an arrow 1 m long from the base along its heading (one row per step)."""
PATH = "world/path"
"""The best particle's pose at each step as a segment from the one before; the map view shows this
entity from the start of the timeline to the cursor: the path so far."""
OCCUPANCY = "world/occupancy"
"""`gslam process --occupancy`: the final trinary grid as an image under the map (light grey occupied,
dark free, unknown transparent), placed by its origin and cell size."""
TRAJECTORY = "world/trajectory"
"""The best particle's final trajectory."""
SESSIONS = "world/sessions"
"""The final trajectories of the earlier mapping runs a continued run goes on from (`session_trajectory`)."""


def session_trajectory(k: int) -> str:
    """The entity of earlier run k's final trajectory (0: the first)."""
    return f"{SESSIONS}/{k}/trajectory"


def session_robot(k: int) -> str:
    """Earlier run k's robot (an arrow) along its final trajectory, on its own timelines (`session_timeline`)."""
    return f"{SESSIONS}/{k}/robot"


def session_timeline(k: int, kind: str) -> str:
    """Earlier run k's timeline: "scan" (sequence) or "time" (seconds since its first scan)."""
    return f"session {k} {kind}"


GRAPH_NODES = "world/graph/nodes"
"""The back end's pose graph (final): its nodes at their optimised poses."""
GRAPH_SEQUENTIAL = "world/graph/sequential"
"""... the edges between consecutive nodes (the placed motion)."""
GRAPH_CLOSURES = "world/graph/closures"
"""... the loop closures the optimisation kept (green)."""
GRAPH_REJECTED = "world/graph/rejected"
"""... and those it rejected (red)."""
ONLINE = "world/online"
"""The online estimate: the best particle's pose at each step."""
GRID_OCCUPANCY = "grid/occupancy"
"""The grid baselines' occupancy image (final)."""

STATS_EFFECTIVE_SAMPLE_SIZE = "stats/effective_sample_size"
STATS_MAP_POINTS = "stats/map_points"
STATS_STEP_MS = "stats/step_ms"
STATS = {
    "effective_sample_size": STATS_EFFECTIVE_SAMPLE_SIZE,
    "map_points": STATS_MAP_POINTS,
    "step_ms": STATS_STEP_MS,
}
"""The per-step statistics by name (their time series)."""

LEGEND = "legend"
"""What the map's colours mean (a static markdown text document), outside `world` so that the map view
does not draw it; the default blueprint shows it under the plots."""
