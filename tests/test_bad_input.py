"""Bad input: one clear line naming file and line, non-zero exit, nothing half-written."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from ingest import IngestError, ingest
from ingest.textlog import monotone_log_times_ns, parse_numeric_csv
from pipelines.cli.app import app


def write_sydney(d: Path, laser_lines: list[str] | None = None, drs: str | None = None) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    (d / "DRS.txt").write_text(drs if drs is not None else "1.0,2.0,0.1\n1.025,2.0,0.1\n1.05,2.0,0.1\n")
    (d / "GPS.txt").write_text("1.0,0.0,0.0\n1.2,0.4,0.0\n")
    ranges = ",".join(["5.0"] * 361)
    lines = laser_lines if laser_lines is not None else [f"1.01,{ranges}", f"1.22,{ranges}"]
    (d / "LASER.txt").write_text("\n".join(lines) + "\n")
    return d


def run_cli(*args: str):
    return CliRunner().invoke(app, list(args))


def assert_one_line_error(result, *fragments: str) -> None:
    assert result.exit_code != 0
    text = result.output.strip()
    assert "Traceback" not in text
    lines = [ln for ln in text.splitlines() if ln.strip()]
    assert len(lines) == 1, text
    for f in fragments:
        assert f in lines[0], lines[0]


def test_wrong_column_count_names_file_and_line(tmp_path):
    ranges = ",".join(["5.0"] * 300)
    src = write_sydney(tmp_path / "log", [f"1.01,{','.join(['5.0'] * 361)}", f"1.22,{ranges}"])
    out = tmp_path / "out.mcap"
    result = run_cli("ingest", str(src), "-o", str(out))
    assert_one_line_error(result, "LASER.txt:2", "expected 362")
    assert not out.exists()
    assert not list(tmp_path.glob(".out.mcap*")), "temporary file left behind"


def test_non_number(tmp_path):
    src = write_sydney(tmp_path / "log", drs="1.0,2.0,0.1\n1.025,abc,0.1\n")
    assert_one_line_error(run_cli("ingest", str(src), "-o", str(tmp_path / "o.mcap")), "DRS.txt:2", "not a number")


def test_nan_range(tmp_path):
    r = ["5.0"] * 361
    r[10] = "nan"
    src = write_sydney(tmp_path / "log", [f"1.01,{','.join(r)}"])
    assert_one_line_error(run_cli("ingest", str(src), "-o", str(tmp_path / "o.mcap")), "LASER.txt:1", "non-finite")


def test_negative_range(tmp_path):
    r = ["5.0"] * 361
    r[7] = "-1.5"
    src = write_sydney(tmp_path / "log", [f"1.01,{','.join(['5.0'] * 361)}", f"1.22,{','.join(r)}"])
    assert_one_line_error(
        run_cli("ingest", str(src), "-o", str(tmp_path / "o.mcap")), "LASER.txt:2", "negative range", "beam 7"
    )


def test_skip_bad_lines_reports_count(tmp_path):
    ranges = ",".join(["5.0"] * 361)
    src = write_sydney(tmp_path / "log", [f"1.01,{ranges}", "1.1,1,2,3", f"1.22,{ranges}", "junk"])
    report = ingest(src, tmp_path / "o.mcap", skip_bad_lines=True)
    assert report.counts["/laser/scan"] == 2
    assert any("skipped 2 malformed lines" in w for w in report.log.warnings)


def test_empty_log(tmp_path):
    src = write_sydney(tmp_path / "log", drs="")
    assert_one_line_error(run_cli("ingest", str(src), "-o", str(tmp_path / "o.mcap")), "DRS.txt", "empty")


def test_missing_source_and_missing_file(tmp_path):
    assert_one_line_error(run_cli("ingest", str(tmp_path / "nope"), "-o", str(tmp_path / "o.mcap")), "nope")
    d = tmp_path / "d"
    d.mkdir()
    (d / "GPS.txt").write_text("1,2,3\n")
    assert_one_line_error(run_cli("ingest", str(d), "-o", str(tmp_path / "o.mcap")), "no known log")


def test_backwards_timestamps_are_kept_in_file_order(tmp_path):
    ranges = ",".join(["5.0"] * 361)
    src = write_sydney(tmp_path / "log", [f"1.30,{ranges}", f"1.20,{ranges}", f"1.40,{ranges}"])
    report = ingest(src, tmp_path / "o.mcap")
    assert any("1 timestamps go backwards" in w for w in report.log.warnings)
    from mcaplog import channels as ch
    from mcaplog.mcapio import McapInput

    stamps = [ch.t_of(m.value.timestamp) for m in McapInput(tmp_path / "o.mcap").messages([ch.LASER])]
    assert stamps == pytest.approx([1.30, 1.20, 1.40])


def test_carmen_malformed_line(tmp_path):
    log = tmp_path / "x.clf"
    log.write_text("FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 10.0 host 10.0\nFLASER 3 1.0 2.0\n")
    assert_one_line_error(run_cli("ingest", str(log), "-o", str(tmp_path / "o.mcap")), "x.clf:2", "FLASER")


def test_process_rejects_non_gslam_mcap(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap")
    assert_one_line_error(run_cli("process", str(bad), str(tmp_path / "out.mcap"), "--no-rrd"), "bad.mcap")
    assert not (tmp_path / "out.mcap").exists()


def test_unknown_filter_option(tmp_path):
    src = write_sydney(tmp_path / "log")
    ingest(src, tmp_path / "in.mcap")
    res = run_cli("process", str(tmp_path / "in.mcap"), str(tmp_path / "out.mcap"), "--set", "bogus=1")
    assert_one_line_error(res, "bogus")


def test_monotone_log_times():
    t, back = monotone_log_times_ns(np.array([1.0, 2.0, 1.5, 2.0, 3.0]))
    assert back == 1
    assert (np.diff(t) > 0).all()
    assert t[0] == 1_000_000_000 and t[-1] == 3_000_000_000


finite = st.floats(allow_nan=False, allow_infinity=False, width=32)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.lists(finite, min_size=3, max_size=3), min_size=1, max_size=20))
def test_parser_round_trips_valid_rows(rows):
    text = "\n".join(",".join(repr(float(v)) for v in row) for row in rows) + "\n"
    table = parse_numeric_csv(Path("mem.txt"), 3, text=text)
    np.testing.assert_array_equal(table.rows, np.array(rows, dtype=float))
    assert list(table.line_numbers) == list(range(1, len(rows) + 1))


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet="0123456789.,-e\nnaNIf x", max_size=200))
def test_parser_never_fails_unclearly(text):
    """Arbitrary text: either parsed rows of 3 finite numbers, or an IngestError naming the file."""
    try:
        table = parse_numeric_csv(Path("mem.txt"), 3, text=text)
    except IngestError as e:
        assert str(e).startswith("mem.txt")
    else:
        assert table.rows.shape[1] == 3
        assert np.isfinite(table.rows).all()


def _child_processes() -> list[int]:
    """Processes whose parent is this one (Linux /proc)."""
    me, out = os.getpid(), []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == me:
                out.append(int(entry))
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc to list child processes")
def test_a_run_that_cannot_start_ends_the_rerun_writer_it_started_and_leaves_no_files(tmp_path):
    """`gslam process` starts the Rerun writer's process before it reads its input or its options: when
    those fail, that process is ended and no recording or temporary is left."""
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap")
    before = set(_child_processes())
    assert_one_line_error(run_cli("process", str(bad), str(tmp_path / "out.mcap")), "bad.mcap")
    src = write_sydney(tmp_path / "log")
    ingest(src, tmp_path / "in.mcap")
    res = run_cli("process", str(tmp_path / "in.mcap"), str(tmp_path / "out2.mcap"), "--set", "bogus=1")
    assert_one_line_error(res, "bogus")
    assert set(_child_processes()) <= before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap", "in.mcap", "log"]
