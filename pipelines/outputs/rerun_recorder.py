"""The Rerun recording's child writer (`python -m pipelines.outputs.rerun_recorder`), fed by `RerunResultWriter`.

The recording is written in a process of its own so that importing rerun (and the pyarrow it pulls in),
building the blueprint and encoding the rows run on another core than the filter, and the filter's
process does not hold rerun's memory. Plain data only: numpy arrays in pickled commands on stdin, one
JSON line per reply on stdout. It imports numpy and rerun, nothing of the filter.

Commands (`pipelines.outputs.writer_child`): ("open", path, app_id, gps, landmarks, live_url), then any number of
("rows", ...) and ("map", ...), then ("finish", final) or ("abort",). The file at `path` is the caller's
temporary: the caller renames it once "finish" is answered. When stdin closes without "finish" or
"abort" (the caller was killed) the rows received are flushed and the temporary is left, as the
caller's own temporaries are, for the next run to remove.
"""

from __future__ import annotations

import errno
import importlib.abc
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pipelines.outputs import rerun_entities as entity
from pipelines.outputs import writer_child

if TYPE_CHECKING:
    import rerun.blueprint as rrb


def probability_colors(p: np.ndarray) -> np.ndarray:
    """RGBA uint8 colours from blue (low) through green to red (high) for p scaled to its maximum."""
    if len(p) == 0:
        return np.empty((0, 4), dtype=np.uint8)
    v = np.clip(p / max(float(p.max()), 1e-300), 0.0, 1.0)
    r = np.clip(2 * v - 0.5, 0, 1)
    g = np.clip(1.5 - np.abs(4 * v - 2), 0, 1)
    b = np.clip(1.5 - 2 * v, 0, 1)
    return (np.column_stack([r, g, b, np.ones_like(v)]) * 255).astype(np.uint8)


MAP_COLOURS = (
    "**Colours**: map points coloured by probability of an obstacle: blue low -> green -> red high (scaled to "
    "the map's maximum). Paths: final white, online blue, so far gold; GPS green, scan magenta, particles orange."
)
"""The map's colour scale (`probability_colors`) and the lines' colours, in words: logged as a text document
(`rerun_entities.LEGEND`) that the default blueprint shows under the plots."""


SERIES = {
    "effective_sample_size": ("effective sample size", (130, 200, 70)),
    "map_points": ("map points", (230, 70, 90)),
    "step_ms": ("step time [ms]", (70, 190, 210)),
}
"""Each statistic (`rerun_entities.STATS`): its plot's title and its line's colour, fixed rather than left to
the viewer's choice, so that a user (and a screenshot) finds each line by its colour in every recording."""

FINAL_PATH_RADIUS_UI = 1.0
"""The final path's radius in screen points (a line 2 points wide at any zoom): as thin as the GPS track
(0.08 m) at the Car Park's usual zoom, so that a corridor's free space stays visible beside it."""
ONLINE_PATH_RADIUS_UI = 0.75
"""The online estimate's radius in screen points, under the final path where they agree."""
SESSION_COLOURS = ([255, 170, 60], [200, 90, 255], [60, 220, 220], [255, 110, 160])
"""The earlier mapping runs' final paths (`world/sessions/K`): orange, violet, cyan, pink, then again."""


def blueprint() -> rrb.Blueprint:
    """The default layout: the map (north up) takes three quarters of the width; beside it the three
    statistics plots and, small, the legend of the colours (`MAP_COLOURS`).

    Each plot shows its statistic from the start up to the time cursor, on a time axis that spans the whole
    timeline, so that it fills as the run goes (live) or as the cursor moves (replay). Left to the viewer
    (rerun 0.41), a plot's time axis is a window of +-30 s (+-1000 scans) around the cursor once its data
    span more than 60 s (2000 scans): a minute of the run rather than the run so far, and in the web viewer,
    with the cursor put at 60 s of the Car Park log, the plots were drawn empty."""
    import rerun as rr
    import rerun.blueprint as rrb

    so_far = rrb.VisibleTimeRanges(
        [
            rrb.VisibleTimeRange(
                timeline, start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative()
            )
            for timeline in (entity.SCAN_TIMELINE, entity.TIME_TIMELINE)
        ]
    )
    whole_run = rrb.TimeAxis(
        view_range=rr.TimeRange(start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())
    )

    def plot(name: str) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(name=SERIES[name][0], origin=entity.STATS[name], time_ranges=so_far, axis_x=whole_run)

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(
                name="map (north / y up)",
                origin="/",
                contents=f"/{entity.WORLD}/**",
                overrides={entity.PATH: so_far},
                background=[18, 20, 26],  # dark: the white final path and the map's colours stand out
            ),
            rrb.Vertical(
                *(plot(name) for name in entity.STATS),
                rrb.TextDocumentView(name="colours", origin=entity.LEGEND),
                row_shares=[3, 3, 3, 2],
            ),
            column_shares=[3, 1],
        ),
        # The blueprint panel (the entities to show or hide) and the time panel (the cursor) open, as a user
        # needs them; the selection panel, empty until something is clicked, closed to leave the map the room.
        rrb.BlueprintPanel(state="expanded"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="expanded"),
    )


class Recorder:
    """Writes the recording (`world/*` on the `scan` and `time` timelines, `stats/*`, `grid/*`)."""

    def __init__(
        self,
        path: str,
        app_id: str,
        gps: np.ndarray | None,
        landmarks: np.ndarray | None,
        live_url: str | None = None,
    ) -> None:
        """`live_url`: also stream to the Rerun viewer (or `rerun --serve-web`) listening there (`--live`)."""
        import rerun as rr

        self.rr = rr
        self.path = Path(path)
        self.rec = rr.RecordingStream(app_id)
        # Only the log's own timelines (`scan`, `time`): the wall-clock `log_time` and the call counter
        # `log_tick` that rerun adds by default mean nothing for a replayed log.
        self.rec.set_log_time_enabled(False)
        self.rec.set_log_tick_enabled(False)
        if live_url:
            self.rec.set_sinks(rr.FileSink(str(self.path)), rr.GrpcSink(live_url), default_blueprint=blueprint())
        else:
            self.rec.save(str(self.path), default_blueprint=blueprint())
        self.rec.log(entity.WORLD, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)  # y up: entity.WORLD
        self.rec.log(entity.LEGEND, rr.TextDocument(MAP_COLOURS, media_type=rr.MediaType.MARKDOWN), static=True)
        # Colours and sizes of the per-step points, once for the whole recording (radii in screen points
        # stay visible at any zoom).
        ui = rr.components.Radius.ui_points
        self.rec.log(entity.SCAN, rr.Points2D.from_fields(colors=[[255, 60, 200]], radii=ui(2.0)), static=True)
        self.rec.log(entity.PARTICLES, rr.Points2D.from_fields(colors=[[255, 140, 0]], radii=ui(3.5)), static=True)
        self.rec.log(entity.ROBOT, rr.Arrows2D.from_fields(colors=[[255, 255, 255]], radii=ui(2.5)), static=True)
        self.rec.log(entity.PATH, rr.LineStrips2D.from_fields(colors=[[255, 215, 60]], radii=ui(1.5)), static=True)
        for name, (title, colour) in SERIES.items():
            self.rec.log(entity.STATS[name], rr.SeriesLines(colors=[colour], names=[title]), static=True)
        if gps is not None and len(gps):
            self.rec.log(entity.GPS, rr.LineStrips2D([gps[:, 1:3]], colors=[[40, 200, 40]], radii=0.08), static=True)
        if landmarks is not None and len(landmarks):
            self.rec.log(
                entity.LANDMARKS,
                rr.Points2D(
                    landmarks,
                    colors=[[255, 200, 0]],
                    radii=0.4,
                    labels=[f"pole {i + 1}" for i in range(len(landmarks))],
                ),
                static=True,
            )

    def _set_time(self, scan: int, time_s: float) -> None:
        self.rec.set_time(entity.SCAN_TIMELINE, sequence=scan)
        self.rec.set_time(entity.TIME_TIMELINE, duration=time_s)

    def rows(
        self,
        scans: np.ndarray,
        times_s: np.ndarray,
        columns: dict[str, tuple[np.ndarray, np.ndarray]],
        poses: np.ndarray | None = None,
        stats: dict[str, np.ndarray] | None = None,
    ) -> None:
        """One row per step on each path: `columns[path]` = (all the steps' points, points per step); the
        robot's arrow and path segment from `poses` (K, 4: x, y, heading, and the path's previous x, y in
        columns 3-4 as a (K, 5) array); the statistics as they come, so the plots fill while the run goes."""
        rr = self.rr
        idx = [
            rr.TimeColumn(entity.SCAN_TIMELINE, sequence=scans),
            rr.TimeColumn(entity.TIME_TIMELINE, duration=times_s),
        ]
        for path, (points, counts) in columns.items():
            self.rec.send_columns(path, indexes=idx, columns=rr.Points2D.columns(positions=points).partition(counts))
        if poses is not None and len(poses):
            heading = np.column_stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])])
            self.rec.send_columns(
                entity.ROBOT, indexes=idx, columns=rr.Arrows2D.columns(origins=poses[:, :2], vectors=heading)
            )
            segments = np.stack([poses[:, 3:5], poses[:, :2]], axis=1).reshape(-1, 2)
            self.rec.send_columns(
                entity.PATH, indexes=idx, columns=rr.LineStrips2D.columns(strips=list(segments.reshape(-1, 2, 2)))
            )
        for name, path in entity.STATS.items():
            if stats is not None and name in stats:
                self.rec.send_columns(path, indexes=idx, columns=rr.Scalars.columns(scalars=stats[name]))

    def map(self, scan: int, time_s: float, xy: np.ndarray, p: np.ndarray) -> None:
        self._set_time(scan, time_s)
        self.rec.log(entity.MAP, self.rr.Points2D(xy, colors=probability_colors(p), radii=0.07))

    def finish(self, final: dict[str, Any]) -> None:
        """The final map, landmarks, grids and trajectories (the statistics came with the rows, as the run
        went); then close the file."""
        rr, rec = self.rr, self.rec
        last = final.get("last")
        if last is not None:
            self.map(int(last[0]), float(last[1]), *final["map"])
            if final.get("landmark_ellipses") is not None:
                rec.log(
                    entity.LANDMARK_ELLIPSES,
                    rr.LineStrips2D(final["landmark_ellipses"], colors=[[0, 200, 255]], radii=0.03),
                )
            if final.get("occupancy_image") is not None:
                rec.log(entity.GRID_OCCUPANCY, rr.Image(final["occupancy_image"]))
            nav = final.get("navigation_grid")
            if nav is not None:  # (state rows along y, origin, cell size): pixel (ix, iy) on its cell
                state, origin, cell = nav
                rgba = np.zeros((*state.shape, 4), dtype=np.uint8)  # unknown: transparent
                rgba[state == 0] = (55, 60, 70, 255)  # free: dark, under the map's points and the paths
                rgba[state == 100] = (170, 170, 170, 255)  # occupied: light grey
                rec.log(
                    entity.OCCUPANCY,
                    rr.Transform3D(translation=[float(origin[0]), float(origin[1]), 0.0], scale=[cell, cell, 1.0]),
                    rr.Image(rgba, color_model="RGBA", draw_order=-10.0),
                )
            # The final path in white (the map's colours run blue to red), the online estimate in blue; thin
            # lines on top of the rest, so that the free space, the map and the GPS track show beside them.
            ui = rr.components.Radius.ui_points
            rec.log(
                entity.TRAJECTORY,
                rr.LineStrips2D(
                    [final["trajectory"]], colors=[[255, 255, 255]], radii=ui(FINAL_PATH_RADIUS_UI), draw_order=40.0
                ),
            )
            rec.log(
                entity.ONLINE,
                rr.LineStrips2D(
                    [final["online"]], colors=[[60, 120, 255]], radii=ui(ONLINE_PATH_RADIUS_UI), draw_order=39.0
                ),
            )
            for k, t_s, poses in final.get("sessions") or []:  # the runs this one continues, in its map
                colour = SESSION_COLOURS[k % len(SESSION_COLOURS)]
                rec.log(
                    entity.session_trajectory(k),
                    rr.LineStrips2D([poses[:, :2]], colors=[colour], radii=ui(1.0), draw_order=38.0),
                )
                # its robot on a timeline of its own: that run replayed along its final path
                idx = [
                    rr.TimeColumn(entity.session_timeline(k, "scan"), sequence=np.arange(len(t_s))),
                    rr.TimeColumn(entity.session_timeline(k, "time"), duration=t_s - t_s[0]),
                ]
                heading = np.column_stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])])
                rec.send_columns(
                    entity.session_robot(k), indexes=idx,
                    columns=rr.Arrows2D.columns(origins=poses[:, :2], vectors=heading, colors=[colour] * len(t_s)),
                )  # fmt: skip
            graph = final.get("graph")
            if graph is not None:
                rec.log(entity.GRAPH_NODES, rr.Points2D(graph["nodes"], colors=[[200, 200, 200]], radii=ui(2.0)))
                for path, color in (
                    (entity.GRAPH_SEQUENTIAL, [150, 150, 150]),
                    (entity.GRAPH_CLOSURES, [60, 220, 90]),
                    (entity.GRAPH_REJECTED, [230, 50, 50]),
                ):
                    key = path.rsplit("/", 1)[1]
                    rec.log(path, rr.LineStrips2D(graph[key], colors=[color], radii=ui(1.0), draw_order=41.0))
        self.finish_file()

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()

    def finish_file(self) -> None:
        """Close the recording and check that all of it reached the disk: rerun's file sink reports a
        failed write (a full disk, an I/O error) only in its log, so the file must end with the RRD
        footer rerun writes last; a file that does not is refused, naming the cause when it is a full disk."""
        try:
            self.close()
        except RuntimeError as e:  # rerun's file writer thread gave up
            full = _disk_full(self.path.parent)
            raise OSError(
                errno.ENOSPC if full else errno.EIO,
                "No space left on device" if full else f"rerun could not write it ({str(e).splitlines()[0]})",
            ) from None
        with open(self.path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            f.seek(max(0, size - len(RRD_END) - 4))
            tail = f.read()
        if RRD_END not in tail:
            full = _disk_full(self.path.parent)
            raise OSError(
                errno.ENOSPC if full else errno.EIO,
                "No space left on device: the recording was cut short" if full else "the recording was cut short",
            )

    def abort(self) -> None:
        self.close()
        self.path.unlink(missing_ok=True)


RRD_END = b"RRF2FOOT"
"""The last record of an RRD file (its footer's magic, then a 4-byte version), written when the file sink
closes."""


def _disk_full(directory: Path) -> bool:
    try:
        return os.statvfs(directory).f_bavail == 0
    except OSError:
        return False


class _NoPandas(importlib.abc.MetaPathFinder):
    """Refuses to import pandas (see `main`)."""

    def find_spec(self, name, path=None, target=None):
        if name == "pandas" or name.startswith("pandas."):
            raise ModuleNotFoundError("pandas is not used by the Rerun writer", name=name)
        return None


def main() -> int:
    # pyarrow (under rerun) imports pandas, when installed, at its first array: time and memory the
    # recording never uses. Refusing the import here is what pyarrow sees when pandas is not installed.
    sys.meta_path.insert(0, _NoPandas())
    # Imported now, not at "open" (`writer_child.start_rerun_writer` says why). A failure here is left
    # for "open" to report.
    try:
        import rerun  # noqa: F401
        import rerun.blueprint  # noqa: F401
    except Exception:
        pass
    return writer_child.main(Recorder)


if __name__ == "__main__":
    sys.exit(main())
