"""The Rerun recording's child writer (`pipelines.outputs.rerun_recorder`): what it imports, what it writes, and what
the filter's process does when it stops or is told to abort."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gslam.scan import ScanGeometry
from pipelines.errors import OutputError
from pipelines.outputs.rerun_result import RerunResultWriter
from pipelines.outputs.writer import RunEnd

ROOT = Path(__file__).resolve().parents[1]
GEOMETRY = ScanGeometry(181, -np.pi / 2, np.pi / 180, 30.0)


def test_the_writer_imports_neither_the_filter_nor_pandas():
    """The writer holds rerun's memory, not the filter's; pandas (which pyarrow would pull in) is refused."""
    code = (
        "import sys, pipelines.outputs.rerun_recorder as w; sys.meta_path.insert(0, w._NoPandas()); "
        "import rerun, pyarrow as pa; pa.array(['a']); "
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'gslam', 'numba', 'pandas', 'mcap', 'scipy'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


class _Flt:
    """The little of a filter the recording reads at the end."""

    def best_particle(self) -> int:
        return 0

    def map_points(self, particle: int):
        return np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([0.9, 0.6])

    def best_trajectory(self):
        return np.arange(3.0), np.zeros((3, 3))


def _opened(writer: RerunResultWriter, landmarks: np.ndarray | None) -> RerunResultWriter:
    writer.open(GEOMETRY, 0.0, None, landmarks)
    return writer


def _rows(writer: RerunResultWriter, n: int) -> None:
    for i in range(n):
        writer.stats["scan"].append(i)
        writer.stats["time"].append(0.1 * i)
        for key in ("ess", "map", "ms"):
            writer.stats[key].append(1.0)
        writer.pending_scans.append((np.full(181, 5.0), np.array([0.1 * i, 0.0, 0.0]), GEOMETRY.bearings_rad))
        writer.pending_particles.append(np.zeros((4, 2)))
        writer.online.append(np.zeros(2))


def test_a_recording_is_written_through_its_temporary(tmp_path):
    out = tmp_path / "r.rrd"
    writer = _opened(RerunResultWriter(out, 0), np.array([[1.0, 1.0]]))
    _rows(writer, 250)
    writer._flush()
    assert not out.exists()
    assert writer.finish(RunEnd(_Flt(), {})) == out
    assert out.stat().st_size > 10_000 and not list(tmp_path.glob(".*.tmp"))
    assert writer.writer.peak_rss_mb > 10
    rerun = Path(sys.executable).with_name("rerun")
    if rerun.exists():
        verify = subprocess.run([rerun, "rrd", "verify", str(out)], capture_output=True, text=True, timeout=120)
        assert verify.returncode == 0, verify.stderr


def test_a_writer_that_stopped_is_one_clear_error_and_leaves_nothing(tmp_path):
    out = tmp_path / "r.rrd"
    writer = _opened(RerunResultWriter(out, 0), None)
    _rows(writer, 10)
    writer.writer.proc.kill()
    writer.writer.proc.wait()
    with pytest.raises(OutputError, match=r"r\.rrd: the writer of the Rerun recording stopped"):
        writer.finish(RunEnd(_Flt(), {}))
    writer.abort()
    assert not out.exists() and not list(tmp_path.glob(".*.tmp"))


def test_abort_removes_the_temporary(tmp_path):
    out = tmp_path / "r.rrd"
    writer = _opened(RerunResultWriter(out, 0), None)
    _rows(writer, 10)
    writer._flush()
    writer.abort()
    assert writer.writer.proc.returncode is not None
    assert not out.exists() and not list(tmp_path.glob(".*.tmp"))


def test_a_map_snapshot_is_sent_as_a_copy_not_a_view_of_the_filters_buffer(tmp_path):
    """A view waiting in the sender's queue would keep the filter's map buffer referenced, and the map
    update could not write that buffer again (gslam.mapupdate.windowed.UpdateWorkspace)."""
    from types import SimpleNamespace

    buffer_xy, buffer_p = np.arange(40.0).reshape(20, 2), np.linspace(0.5, 1.0, 20)

    class Flt(_Flt):
        def map_points(self, particle: int):
            return buffer_xy[5:15], buffer_p[5:15]

    writer = _opened(RerunResultWriter(tmp_path / "s.rrd", 25), None)
    sent = []
    writer.writer.send = sent.append
    result = SimpleNamespace(
        poses=np.zeros((3, 3)), best_pose=np.zeros(3), best=0, effective_sample_size=3.0, map_points=10
    )
    event = SimpleNamespace(index=25, t_s=2.5, ranges_m=np.full(181, 5.0), geometry=GEOMETRY)
    writer.step(SimpleNamespace(result=result, event=event, step_ms=1.0, laser_pose=np.zeros(3)), Flt())
    (snapshot,) = [c for c in sent if c[0] == "map"]
    _, scan, _, xy, p = snapshot
    assert scan == 25
    np.testing.assert_allclose(xy, buffer_xy[5:15])
    np.testing.assert_allclose(p, buffer_p[5:15], rtol=1e-6)
    assert not np.shares_memory(xy, buffer_xy) and not np.shares_memory(p, buffer_p)
    writer.abort()


# --- the recording of a real run (the Car Park log) ------------------------------------------------------
@pytest.fixture(scope="module")
def carpark_rrd(carpark_mcap, tmp_path_factory) -> Path:
    """`gslam process` of the whole Car Park log (586 scans, N 8): its recording."""
    from typer.testing import CliRunner

    from pipelines.cli.app import app

    out = tmp_path_factory.mktemp("carpark_rrd") / "cp.mcap"
    result = CliRunner().invoke(app, ["process", str(carpark_mcap), str(out), "-N", "8"])
    assert result.exit_code == 0, result.output
    return out.with_suffix(".rrd")


def _recorded(rrd: Path, blueprint: bool = False) -> dict[str, list[dict]]:
    """The rows of the recording (or of its blueprint) by entity path, each a dict of its columns (the
    row id as bytes: rerun's row ids grow in the order the rows were logged)."""
    import rerun.chunk

    reader = rerun.chunk.RrdReader(str(rrd))
    store = reader.blueprints()[0] if blueprint else reader.recordings()[0]
    rows: dict[str, list[dict]] = {}
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        columns = {name: batch.column(name).to_pylist() for name in batch.schema.names}
        for i in range(batch.num_rows):
            rows.setdefault(chunk.entity_path, []).append({name: values[i] for name, values in columns.items()})
    return rows


def _union_kinds(rrd: Path, path: str, column: str) -> list[tuple[str, str]]:
    """(start, end) of each time range in a blueprint column, by the kind of bound ("Infinite",
    "CursorRelative", "Absolute") rather than its value."""
    import rerun.chunk

    reader = rerun.chunk.RrdReader(str(rrd))
    kinds = []
    for chunk in reader.stream(store=reader.blueprints()[0]):
        if chunk.entity_path != path:
            continue
        ranges = chunk.to_record_batch().column(column).flatten()
        if "range" in ranges.type.names:  # VisibleTimeRange: (timeline, range)
            ranges = ranges.field("range")
        start, end = ranges.field("start"), ranges.field("end")
        names = [[u.type.field(int(c)).name for c in u.type_codes.to_pylist()] for u in (start, end)]
        kinds += list(zip(*names, strict=True))
    return kinds


def test_every_statistic_is_on_the_timeline_at_each_step_as_the_run_goes(carpark_rrd):
    """The statistics plots fill while the run goes: each statistic has a value at every step, sent with
    the steps as they go (the rows of most steps were logged before the last map snapshot the run sent),
    not at the finish; and each plot shows its statistic up to the time cursor on a time axis spanning the
    whole run (the viewer's own fallback, +-30 s around the cursor, drew them empty mid-run)."""
    from pipelines.outputs import rerun_entities as entity

    rows = _recorded(carpark_rrd)
    series = {path: [r for r in rows["/" + path] if "Scalars:scalars" in r] for path in entity.STATS.values()}
    for path, values in series.items():  # (beside the static line colour and name)
        assert sorted(r[entity.SCAN_TIMELINE] for r in values) == list(range(586)), path
    points = sorted(series[entity.STATS_MAP_POINTS], key=lambda r: r[entity.SCAN_TIMELINE])
    values = [r["Scalars:scalars"][0] for r in points]
    assert len(set(values)) > 50 and values[0] < 1000 < 3000 < values[-1]  # the map grows along the run
    snapshots = [r for r in rows["/" + entity.MAP] if r[entity.SCAN_TIMELINE] < 585]  # sent during the run
    last_snapshot = max(snapshots, key=lambda r: r[entity.SCAN_TIMELINE])["rerun.controls.RowId"]
    before = [r for r in points if r["rerun.controls.RowId"] < last_snapshot]
    assert len(before) > len(points) / 2, len(before)
    blueprint = _recorded(carpark_rrd, blueprint=True)
    plots = [p for p, r in blueprint.items() if r[0].get("ViewBlueprint:class_identifier") == ["TimeSeries"]]
    assert len(plots) == 3
    for plot in plots:
        assert _union_kinds(carpark_rrd, f"{plot}/TimeAxis", "TimeAxis:view_range") == [("Infinite", "Infinite")]
        shown = _union_kinds(carpark_rrd, f"{plot}/VisibleTimeRanges", "VisibleTimeRanges:ranges")
        assert shown == [("Infinite", "CursorRelative")] * 2  # on the scan and time timelines


def test_the_final_path_is_drawn_thin_beside_the_gps_track(carpark_rrd):
    """A radius of at most 1 screen point (negative radii are screen points) or 0.1 m: not a band as wide
    as a corridor over the map's free space and the GPS track (0.08 m)."""
    from pipelines.outputs import rerun_entities as entity

    rows = _recorded(carpark_rrd)
    (final,) = rows["/" + entity.TRAJECTORY]
    (radius,) = final["LineStrips2D:radii"]
    assert -1.0 <= radius < 0 or 0 < radius <= 0.1, radius
    assert len(final["LineStrips2D:strips"][0]) == 586
    (gps,) = rows["/" + entity.GPS]
    assert gps["LineStrips2D:radii"] == [pytest.approx(0.08)]
    (online,) = rows["/" + entity.ONLINE]
    assert abs(online["LineStrips2D:radii"][0]) <= abs(radius)


def test_the_recording_says_what_the_map_colours_mean_and_gives_the_map_most_of_the_room(carpark_rrd):
    from pipelines.outputs import rerun_entities as entity

    (legend,) = _recorded(carpark_rrd)["/" + entity.LEGEND]
    text = legend["TextDocument:text"][0]
    assert "map points coloured by probability of an obstacle: blue low -> green -> red high" in text
    assert "(scaled to the map's maximum)" in text
    blueprint = _recorded(carpark_rrd, blueprint=True)
    views = {p.removeprefix("/"): r[0] for p, r in blueprint.items() if "ViewBlueprint:class_identifier" in r[0]}
    (shown,) = [v for v in views.values() if v["ViewBlueprint:class_identifier"] == ["TextDocument"]]
    assert shown["ViewBlueprint:space_origin"] == [entity.LEGEND]  # in the default layout
    (the_map,) = [p for p, v in views.items() if v["ViewBlueprint:class_identifier"] == ["2D"]]
    (columns,) = [r[0] for r in blueprint.values() if r[0].get("ContainerBlueprint:col_shares")]
    shares = columns["ContainerBlueprint:col_shares"]
    assert columns["ContainerBlueprint:contents"][0] == the_map and shares[0] / sum(shares) >= 0.7
    (selection,) = blueprint["/selection_panel"]
    assert selection["PanelBlueprint:state"] != [3]  # not expanded: the map takes that room
