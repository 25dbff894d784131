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
