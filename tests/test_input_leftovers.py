"""Input the issue listed as still silently accepted or poorly said: absurd odometry, a UTF-8 byte order
mark, relations that match no scan, a result with no steps, a truncated MCAP, empty or repeated sweep
axes, and a signal while `gslam` starts. Each is one clear line (or the right behaviour)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_reliability import one_line_refusal, run, write_log

from ingest import ingest, read_log
from pipelines.errors import OptionError

FLASER = "FLASER 4 1.0 2.0 81.9 3.5 0 0 0 {x} 0 0 {t:.2f} host {t:.2f}\n"


def carmen_lines(n: int = 5) -> list[str]:
    """A tiny CARMEN log: `n` scans of 4 beams, 0.2 s apart from t = 10 s, driving along x."""
    return [FLASER.format(x=f"{0.1 * i:.2f}", t=10 + 0.2 * i) for i in range(n)]


def ranges_row(t: float) -> str:
    return f"{t:.3f}," + ",".join(["5.0"] * 361)


# ---- 1. absurd odometry ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("line", "fragments"),
    [
        (FLASER.format(x="1e300", t=10.4), ["log.clf:3", "FLASER", "odometry x", "1e+300"]),
        (FLASER.format(x="-2e6", t=10.4), ["log.clf:3", "odometry x", "beyond"]),
        ("ODOM 1e300 0.2 0.05 0.3 0.0 0.0 10.45 host 10.45\n", ["log.clf:3", "ODOM", "odometry x", "1e+300"]),
        ("ODOM 0.1 0.2 0.05 nan 0.0 0.0 10.45 host 10.45\n", ["log.clf:3", "ODOM", "speed", "nan"]),
        ("ODOM 0.1 0.2 0.05 5e3 0.0 0.0 10.45 host 10.45\n", ["log.clf:3", "ODOM", "speed", "5000"]),
        ("ODOM 0.1 0.2 0.05 0.3 inf 0.0 10.45 host 10.45\n", ["log.clf:3", "ODOM", "turn rate", "inf"]),
    ],
    ids=["flaser-1e300", "flaser-2e6", "odom-x-1e300", "odom-tv-nan", "odom-tv-5km/s", "odom-rv-inf"],
)
def test_absurd_carmen_odometry_is_refused_naming_file_and_line(tmp_path, line, fragments):
    lines = carmen_lines()
    lines[2] = line
    log = tmp_path / "log.clf"
    log.write_text("".join(lines))
    out = tmp_path / "o.mcap"
    one_line_refusal(run("ingest", log, "-o", out), *fragments)
    assert not out.exists()


def test_absurd_carmen_odometry_is_dropped_and_counted_with_skip_bad_lines(tmp_path):
    lines = carmen_lines()
    lines[1] = FLASER.format(x="1e300", t=10.2)
    lines[3] = "ODOM 0.1 0.2 0.05 nan 0.0 0.0 10.65 host 10.65\n"
    log = tmp_path / "log.clf"
    log.write_text("".join(lines))
    report = ingest(log, tmp_path / "o.mcap", skip_bad_lines=True)
    assert report.counts["/laser/scan"] == 3
    assert any("skipped 2 malformed lines" in w and "log.clf:2" in w for w in report.log.warnings)


@pytest.mark.parametrize(
    ("drs_row", "fragments"),
    [
        ("1.050,1e300,0.05", ["DRS.txt:3", "speed", "1e+300"]),
        ("1.050,-2000,0.05", ["DRS.txt:3", "speed", "-2000"]),
        ("1.050,2.0,30", ["DRS.txt:3", "steering", "30 rad"]),
        ("1.050,nan,0.05", ["DRS.txt:3", "non-finite"]),
    ],
    ids=["speed-1e300", "speed-2km/s", "steering-30rad", "speed-nan"],
)
def test_absurd_sydney_dead_reckoning_is_refused_naming_file_and_line(tmp_path, drs_row, fragments):
    log = write_log(tmp_path / "log")
    rows = (log / "DRS.txt").read_text().splitlines()
    rows[2] = drs_row
    (log / "DRS.txt").write_text("\n".join(rows) + "\n")
    one_line_refusal(run("ingest", log, "-o", tmp_path / "o.mcap"), *fragments)
    report = ingest(log, tmp_path / "o.mcap", skip_bad_lines=True)
    assert report.counts["/vehicle/odometry"] == len(rows) - 1
    assert any("skipped 1 malformed lines" in w and "DRS.txt:3" in w for w in report.log.warnings)


def test_absurd_victoria_park_dead_reckoning_is_refused_naming_the_variable(tmp_path):
    from scipy.io import savemat

    d = tmp_path / "vp"
    d.mkdir()
    speed = np.full(10, 2.0)
    speed[4] = 1e300
    savemat(d / "aa3_dr.mat", {"time": np.arange(10) * 25.0, "speed": speed, "steering": np.zeros(10)})
    one_line_refusal(run("ingest", d, "-o", tmp_path / "o.mcap"), "aa3_dr.mat", "'speed' index 4", "1e+300")
    steering = np.zeros(10)
    steering[7] = 45.0  # degrees, not radians
    savemat(d / "aa3_dr.mat", {"time": np.arange(10) * 25.0, "speed": np.full(10, 2.0), "steering": steering})
    one_line_refusal(run("ingest", d, "-o", tmp_path / "o.mcap"), "aa3_dr.mat", "'steering' index 7", "45 rad")


# ---- 2. a UTF-8 byte order mark -------------------------------------------------------------------
BOM = b"\xef\xbb\xbf"


def test_a_carmen_log_with_a_bom_gives_the_same_scans_as_without(tmp_path):
    text = "".join(carmen_lines()).encode()
    (tmp_path / "plain.clf").write_bytes(text)
    (tmp_path / "bom.clf").write_bytes(BOM + text)
    plain, bom = read_log(tmp_path / "plain.clf"), read_log(tmp_path / "bom.clf")
    assert len(bom.scan_t_s) == len(plain.scan_t_s) == 5
    np.testing.assert_array_equal(bom.scan_t_s, plain.scan_t_s)
    np.testing.assert_array_equal(bom.scan_ranges_m, plain.scan_ranges_m)
    np.testing.assert_array_equal(bom.odom_pose, plain.odom_pose)
    assert not any("other types" in w for w in bom.warnings), bom.warnings


def test_a_sydney_text_log_with_a_bom_gives_the_same_scans_as_without(tmp_path):
    plain = write_log(tmp_path / "plain")
    bom = write_log(tmp_path / "bom")
    for name in ("DRS.txt", "GPS.txt", "LASER.txt"):
        (bom / name).write_bytes(BOM + (bom / name).read_bytes())
    a, b = read_log(plain), read_log(bom)
    assert len(b.scan_t_s) == len(a.scan_t_s) == 4
    np.testing.assert_array_equal(b.scan_t_s, a.scan_t_s)
    np.testing.assert_array_equal(b.scan_ranges_m, a.scan_ranges_m)
    np.testing.assert_array_equal(b.ackermann, a.ackermann)
    np.testing.assert_array_equal(b.gps, a.gps)
    assert not b.warnings or b.warnings == a.warnings


def test_a_relations_file_with_a_bom_is_read(tmp_path):
    from ingest.carmen import read_relations

    path = tmp_path / "log.relations"
    path.write_bytes(BOM + b"10.0 10.4 0.2 0 0 0 0 0\n")
    np.testing.assert_allclose(read_relations(path), [[10.0, 10.4, 0.2, 0.0, 0.0]])


# ---- 3. relations that match no scan --------------------------------------------------------------
def _carmen_result(tmp_path: Path, relations: str) -> Path:
    from pipelines.process import process
    from pipelines.run.runner import RunConfig

    (tmp_path / "log.clf").write_text("".join(carmen_lines(8)))
    (tmp_path / "log.relations").write_text(relations)
    ingest(tmp_path / "log.clf", tmp_path / "in.mcap")
    process(tmp_path / "in.mcap", tmp_path / "r.mcap", None, RunConfig())
    return tmp_path / "r.mcap"


def test_eval_says_when_no_relation_matched_a_scan(tmp_path):
    result = _carmen_result(tmp_path, "50.0 50.2 0.1 0 0 0 0 0\n60.0 60.4 0.2 0 0 0 0 0\n")
    text = run("eval", result)
    assert text.exit_code == 0, text.output
    assert "note: relations: none of the 2 relations given matched the run's scans" in text.output, text.output
    data = json.loads(run("eval", result, "--json").output)
    assert data["relations_trans_m"] is None
    assert any("none of the 2 relations given matched" in n for n in data["notes"]), data["notes"]


def test_eval_says_how_many_relations_matched_a_scan(tmp_path):
    result = _carmen_result(tmp_path, "10.0 10.4 0.2 0 0 0 0 0\n10.2 10.6 0.2 0 0 0 0 0\n50.0 50.2 0.1 0 0 0 0 0\n")
    data = json.loads(run("eval", result, "--json").output)
    assert data["relations_trans_m"] is not None
    assert any("2 of the 3 relations given matched" in n for n in data["notes"]), data["notes"]


# ---- 4. a result with no steps --------------------------------------------------------------------
@pytest.mark.parametrize("gps", [True, False], ids=["with-gps", "no-gps"])
def test_plot_of_a_result_with_no_steps_is_one_line(tmp_path, monkeypatch, gps):
    from pipelines.process import process
    from pipelines.run import interrupts
    from pipelines.run.runner import RunConfig

    ingest(write_log(tmp_path / "log", gps=gps), tmp_path / "in.mcap")

    def stop_before_the_first_step() -> None:  # a SIGTERM before the first scan was processed
        raise interrupts.Stopped(signal.SIGTERM)

    monkeypatch.setattr(interrupts, "check", stop_before_the_first_step)
    try:
        with pytest.raises(KeyboardInterrupt):
            process(tmp_path / "in.mcap", tmp_path / "r.mcap", None, RunConfig())
    finally:
        interrupts.reset()
    monkeypatch.undo()
    from pipelines.evaluation.mcap_info import mcap_info

    assert mcap_info(tmp_path / "r.mcap")["metadata"]["result"]["steps"] == 0
    out = tmp_path / "p.png"
    one_line_refusal(
        run("plot", tmp_path / "r.mcap", "-o", out),
        "r.mcap: no steps to plot",
        "interrupted (SIGTERM) before its first scan",
    )
    assert not out.exists()


# ---- 5. a truncated MCAP (a killed run's temporary) -----------------------------------------------


@pytest.mark.parametrize("keep", [0, 8, 100, 0.5, -1], ids=["empty", "magic-only", "100-bytes", "half", "last-byte"])
@pytest.mark.parametrize("command", ["eval", "plot", "export", "process"])
def test_a_truncated_mcap_is_said_to_be_truncated_in_one_line(small, tmp_path, keep, command):
    source = small["in"] if command == "process" else small["result"]
    data = source.read_bytes()
    n = int(len(data) * keep) if isinstance(keep, float) else keep if keep >= 0 else len(data) + keep
    cut = tmp_path / f".{source.name}.{2**22 + 1}-12345-0123456789ab.tmp"  # a killed writer's temporary
    cut.write_bytes(data[:n])
    args = {
        "eval": ["eval", cut],
        "plot": ["plot", cut, "-o", tmp_path / "p.png"],
        "export": ["export", cut, "--tum", tmp_path / "t.tum"],
        "process": ["process", cut, tmp_path / "o.mcap", "--no-rrd"],
    }[command]
    if command == "process" and n < 100:  # too short to show gslam's header: refused as no input gslam reads
        line = one_line_refusal(run(*args), str(cut), "not an MCAP from `gslam ingest`")
    else:
        line = one_line_refusal(run(*args), str(cut), "not a finished MCAP")
        assert ("empty" if n == 0 else f"truncated after {n} bytes") in line, line
    assert "RecordLengthLimitExceeded" not in line and "EndOfFile" not in line and "Errno" not in line, line


def test_the_reader_names_a_truncated_file_and_reads_a_finished_one(small, tmp_path):
    from mcaplog.mcapio import McapInput, TruncatedMcap, read_error

    cut = tmp_path / "cut.mcap"
    cut.write_bytes(small["result"].read_bytes()[:-20])
    with pytest.raises(TruncatedMcap) as e:
        McapInput(cut).metadata()
    assert read_error(e.value).startswith("truncated after ")
    assert "result" in McapInput(small["result"]).metadata()  # a finished file reads as before


# ---- 6. sweep specs: empty and repeated axes ------------------------------------------------------
@pytest.mark.parametrize(
    ("body", "fragments"),
    [
        ("inputs = []\n", ["spec.toml:1", "'inputs' is an empty list"]),
        ('inputs = ["a.mcap"]\nseeds = []\n', ["spec.toml:2", "'seeds' is an empty list"]),
        ('inputs = ["a.mcap"]\nparticles = []\n', ["spec.toml:2", "'particles' is an empty list"]),
        ('inputs = ["a.mcap"]\npoints = []\n', ["spec.toml:2", "'points' is an empty list"]),
        ('inputs = ["a.mcap"]\nmethods = []\n', ["spec.toml:2", "'methods' is an empty list"]),
        ('inputs = ["a.mcap"]\nseeds = [0, 0]\n', ["spec.toml:2", "'seeds' lists 0 twice"]),
        ('inputs = ["a.mcap"]\nparticles = [8, 16, 8]\n', ["spec.toml:2", "'particles' lists 8 twice"]),
        ('inputs = ["a.mcap", "./a.mcap"]\n', ["spec.toml:1", "'inputs' lists './a.mcap' twice"]),
        ('inputs = ["a.mcap"]\nmethods = ["gslam", "gslam"]\n', ["spec.toml:2", "'methods' lists 'gslam' twice"]),
        ('inputs = ["a.mcap"]\n[options]\nweight_tempering = []\n', ["spec.toml:3", "weight_tempering' is an empty"]),
        ('inputs = ["a.mcap"]\n[options]\nweight_tempering = [0.3, 0.3]\n', ["spec.toml:3", "lists 0.3 twice"]),
    ],
    ids=[
        "inputs-empty",
        "seeds-empty",
        "particles-empty",
        "points-empty",
        "methods-empty",
        "seeds-repeated",
        "particles-repeated",
        "inputs-repeated",
        "methods-repeated",
        "option-empty",
        "option-repeated",
    ],
)
def test_sweep_specs_with_empty_or_repeated_axes_are_refused_naming_the_key(tmp_path, body, fragments):
    from pipelines.bench.sweep import SweepSpec

    spec = tmp_path / "spec.toml"
    spec.write_text(body)
    with pytest.raises(OptionError) as e:
        SweepSpec.load(spec)
    for f in fragments:
        assert f in str(e.value), str(e.value)
    one_line_refusal(run("sweep", spec, "-o", tmp_path / "out"), *fragments)
    assert not (tmp_path / "out").exists()


def test_a_sweep_spec_with_distinct_values_still_loads(tmp_path):
    from pipelines.bench.sweep import SweepSpec

    spec = tmp_path / "spec.toml"
    spec.write_text('inputs = ["a.mcap", "b.mcap"]\nseeds = [0, 1]\nparticles = [8, 16]\n')
    assert len(SweepSpec.load(spec).tasks()) == 8


# ---- 7. a signal while gslam starts ---------------------------------------------------------------
def _catches(pid: int, sig: int) -> bool | None:
    """Whether process `pid` has a handler for `sig` (/proc's SigCgt mask); None when it has exited."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    caught = int(next(ln for ln in status.splitlines() if ln.startswith("SigCgt:")).split()[1], 16)
    return bool(caught & (1 << (sig - 1)))


@pytest.fixture(scope="module")
def longer_input(tmp_path_factory) -> Path:
    """An input long enough (300 scans) that the run is still going when the signals come."""
    d = tmp_path_factory.mktemp("signals")
    ingest(write_log(d / "log", scans=300), d / "in.mcap")
    return d / "in.mcap"


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
@pytest.mark.parametrize("after_s", [0.05, 0.15, 0.3])
def test_a_signal_while_gslam_starts_exits_128_plus_its_number(longer_input, tmp_path, sig, after_s):
    """The signal lands while the command line imports (typer, numpy, numba) or parses its options: the exit
    code is 128 + its number (typer turned a SIGTERM there into 130) and there is no traceback. The child
    first runs the interpreter's own start-up, where no code of gslam can handle a signal yet; when the
    machine is slow enough that `after_s` falls there, the signal waits until gslam handles it."""
    env = dict(os.environ, GSLAM_PROGRESS="")
    for attempt in range(3):
        out = tmp_path / f"r{attempt}.mcap"
        cmd = [sys.executable, "-m", "pipelines.cli", "process", str(longer_input), str(out), "--no-rrd"]
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(after_s)
        deadline = time.monotonic() + 10
        while _catches(proc.pid, sig) is False and time.monotonic() < deadline:
            time.sleep(0.002)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 128 + sig, (attempt, proc.returncode, err)
        assert "Traceback" not in err and "Exception ignored" not in err, err
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert any(ln.startswith("interrupted") for ln in lines), err
        assert not list(tmp_path.glob(".*.tmp")), "temporary left behind"
        if out.exists():  # the run had begun: its output is finished and marked interrupted
            from pipelines.evaluation.mcap_info import mcap_info

            assert mcap_info(out)["metadata"]["result"]["interrupted"] is True


_WRAPPED_SIGNAL = """
import os, signal, sys, time

class _Lands:
    def __set_name__(self, owner, name):  # Python 3.11 wraps what is raised here in a RuntimeError
        os.kill(os.getpid(), signal.SIG{sig})
        time.sleep(5)

def _a_class_being_made():  # as numba's import makes its classes
    class Kernel:
        field = _Lands()

import pipelines.cli as cli
if sys.argv[1] == "loading":
    import pipelines.cli.app as app
    app.run = _a_class_being_made
    cli.run()
else:
    import typer
    from pipelines.cli.errors import guarded
    from pipelines.run import interrupts
    interrupts.install()
    try:
        guarded(_a_class_being_made)()
    except typer.Exit as e:
        sys.exit(e.exit_code)
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
@pytest.mark.parametrize("where", ["loading", "command"])
def test_a_signal_that_comes_out_wrapped_in_an_error_is_still_the_signal(sig, where):
    """A signal whose handler runs inside a class body being made (numba's import does this) comes out of
    Python 3.11 as a RuntimeError with the signal as its cause. While the command line loads, or in the
    command's body, it still ends with one line and 128 + its number, not a traceback or an internal error
    (CI once saw exit 1 and a traceback from a SIGTERM 0.3 s into `gslam process`)."""
    code = _WRAPPED_SIGNAL.replace("{sig}", sig.name[3:])
    proc = subprocess.run([sys.executable, "-c", code, where], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 128 + sig, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr and "internal error" not in proc.stderr, proc.stderr
    assert "interrupted" in proc.stderr, proc.stderr


def test_a_signal_the_command_did_not_report_sets_the_exit_code():
    """The rule behind the exit codes: a signal raised outside the command's body (typer's silent 130), or
    one whose exception was lost, ends with 128 + its number; one the command reported keeps its code."""
    from pipelines.run import interrupts

    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        interrupts.reset()
        assert interrupts.unreported_exit_code(0) is None  # no signal
        with pytest.raises(interrupts.Stopped):
            interrupts._handler(signal.SIGTERM, None)  # while the command line loads
        assert interrupts.signal_phase() == "before"
        assert interrupts.unreported_exit_code(130) == 143
        interrupts.reset()
        with pytest.raises(interrupts.Stopped), interrupts.stop_on_signals():
            interrupts._handler(signal.SIGTERM, None)  # during the command: it reports it, exit 143
        assert interrupts.signal_phase() == "during"
        assert interrupts.unreported_exit_code(143) is None
        assert interrupts.unreported_exit_code(0) == 143  # reported nowhere: the command ended otherwise
    finally:
        interrupts.reset()
        for s, handler in previous.items():
            signal.signal(s, handler)


def test_a_log_with_no_record_at_all_is_refused_not_written_as_an_empty_mcap(tmp_path):
    """Victoria Park's odometry file with empty arrays (found by the full fuzz profile): nothing to ingest,
    said in one line; nothing at the output."""
    import numpy as np
    import scipy.io

    from ingest import ingest
    from ingest.textlog import IngestError

    log = tmp_path / "vp"
    log.mkdir()
    empty = np.array([], dtype=float)
    scipy.io.savemat(log / "aa3_dr.mat", {"time": empty, "steering": empty, "speed": empty})
    out = tmp_path / "vp.mcap"
    with pytest.raises(IngestError, match="holds no scan, odometry or GPS record"):
        ingest(log, out)
    assert not out.exists()
