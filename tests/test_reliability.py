"""Never lose a user's data, and say plainly what is wrong: one test per class of fault found
by trying to break the command line. Each asserts the exit code, the message, and that every input is
byte for byte what it was."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ingest import ingest
from pipelines.cli.app import app

RANGES = ",".join(["5.0"] * 361)


def write_log(d: Path, gps: bool = True, laser: bool = True, beacons: bool = False, scans: int = 4) -> Path:
    """A tiny Sydney text log: 1 s of odometry at 40 Hz, GPS at 5 Hz, `scans` laser scans."""
    d.mkdir(parents=True, exist_ok=True)
    (d / "DRS.txt").write_text("".join(f"{1 + 0.025 * i:.3f},2.0,0.05\n" for i in range(40 * scans // 4 + 8)))
    if gps:
        (d / "GPS.txt").write_text("".join(f"{1 + 0.2 * i:.3f},{0.4 * i:.3f},0.0\n" for i in range(scans + 2)))
    if laser:
        (d / "LASER.txt").write_text("".join(f"{1.01 + 0.2 * i:.3f},{RANGES}\n" for i in range(scans)))
    if beacons:
        (d / "BEACONS.txt").write_text("3.0,4.0\n-2.0,5.0\n")
    return d


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> dict[str, Path]:
    """A tiny Sydney log, its input MCAP, a result of it, and a tiny CARMEN log."""
    from pipelines.process import process
    from pipelines.run.runner import RunConfig

    d = tmp_path_factory.mktemp("tiny")
    log = write_log(d / "log")
    ingest(log, d / "in.mcap")
    process(d / "in.mcap", d / "r.mcap", None, RunConfig())
    clf = d / "log.clf"
    clf.write_text(
        "".join(
            f"FLASER 4 1.0 2.0 81.9 3.5 0 0 0 {0.1 * i:.2f} 0 0 {10 + 0.2 * i:.2f} h {10 + 0.2 * i:.2f}\n"
            for i in range(5)
        )
    )
    return {"dir": d, "log": log, "in": d / "in.mcap", "result": d / "r.mcap", "clf": clf}


def fingerprint(*paths: Path) -> dict[str, str]:
    """sha256 of every file at or under `paths` (inputs must stay byte for byte the same)."""
    out = {}
    for p in paths:
        for f in [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file()):
            out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def run(*args: str, env: dict[str, str] | None = None):
    return CliRunner().invoke(app, [str(a) for a in args], env=env)


def one_line_refusal(result, *fragments: str) -> str:
    assert result.exit_code == 2, (result.exit_code, result.output)
    lines = [ln for ln in result.output.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, result.output
    line = lines[0]
    assert line.startswith("error: ") and "internal error" not in line and "Traceback" not in line, line
    for f in fragments:
        assert f in line, (f, line)
    return line


# ---- 1. input destroyed ---------------------------------------------------------------------------
OVERWRITES = {
    "ingest -o its own log": (lambda t: ["ingest", t["clf"], "-o", t["clf"]], ["-o", "is the input SOURCE"]),
    "process OUTPUT = INPUT": (lambda t: ["process", t["in"], t["in"]], ["OUTPUT", "is the input INPUT"]),
    "process --rrd = INPUT": (
        lambda t: ["process", t["in"], t["dir"] / "o.mcap", "--rrd", t["in"]],
        ["--rrd", "is the input INPUT"],
    ),
    "export --tum = RESULT": (
        lambda t: ["export", t["result"], "--tum", t["result"]],
        ["--tum", "is the input RESULT"],
    ),
    "ingest -o inside the log": (
        lambda t: ["ingest", t["log"], "-o", t["log"] / "LASER.txt"],
        ["-o", "inside the input directory SOURCE"],
    ),
}


@pytest.mark.parametrize("case", OVERWRITES, ids=list(OVERWRITES))
def test_no_command_writes_over_its_input(tiny, case):
    args, fragments = OVERWRITES[case]
    before = fingerprint(tiny["dir"])
    args = args(tiny)
    line = one_line_refusal(run(*args), *fragments)
    assert str(args[1]) in line and str(args[-1]) in line, line  # names the input and the output
    assert fingerprint(tiny["dir"]) == before


# ---- 2. refused, with the option, file and line, and what was expected -----------------------------
def _toml(t, text: str) -> Path:
    p = t["dir"] / "run.toml"
    p.write_text(text)
    return p


REFUSALS = {
    "--set number is text": (
        lambda t: ["process", t["in"], t["dir"] / "o.mcap", "--set", "match_step_xy_m=abc"],
        ["--set match_step_xy_m=abc", "must be a number", "'abc'"],
    ),
    "--set integer is 3.7": (
        lambda t: ["process", t["in"], t["dir"] / "o.mcap", "--set", "particles=3.7"],
        ["--set particles=3.7", "must be an integer"],
    ),
    "--set NaN": (
        lambda t: ["process", t["in"], t["dir"] / "o.mcap", "--set", "weight_tempering=NaN"],
        ["weight_tempering", "finite"],
    ),
    "TOML integer is text": (
        lambda t: [
            "process",
            t["in"],
            t["dir"] / "o.mcap",
            "--config",
            _toml(t, '[filter]\n# N\nparticles = "eight"\n'),
        ],
        ["run.toml:3", "particles must be an integer", "'eight'"],
    ),
    "--grid-cells -10": (
        lambda t: ["process", t["in"], t["dir"] / "o.mcap", "--grid-cells", "-10"],
        ["'--grid-cells'", "greater than or equal to 16"],
    ),
    "--seed -1": (lambda t: ["process", t["in"], t["dir"] / "o.mcap", "--seed", "-1"], ["'--seed'", "0"]),
    "--max-scans 0": (lambda t: ["process", t["in"], t["dir"] / "o.mcap", "--max-scans", "0"], ["'--max-scans'"]),
    "--method unknown": (
        lambda t: ["process", t["in"], t["dir"] / "o.mcap", "--method", "slam9"],
        ["'--method'", "fastslam1"],
    ),
    "sweep spec value": (
        lambda t: ["sweep", _toml(t, 'inputs = ["x.mcap"]\nparticles = ["abc"]\n'), "-o", t["dir"] / "sw"],
        ["run.toml:2", "particles must be an integer"],
    ),
    "output is a directory": (lambda t: ["process", t["in"], t["dir"]], ["OUTPUT", "is a directory"]),
    "ingest a stray .txt file": (
        lambda t: ["ingest", _toml(t, "").with_name("empty.txt"), "-o", t["dir"] / "o.mcap"],
        ["empty.txt", "a Sydney text log is a directory"],
    ),
    "--vehicle on a CARMEN log": (
        lambda t: ["process", t["carmen_mcap"], t["dir"] / "o.mcap", "--vehicle", "carpark"],
        ["vehicle 'carpark'", "Sydney logs only"],
    ),
    "eval --reference a result": (
        lambda t: ["eval", t["result"], "--reference", t["result"]],
        ["--reference", "is a result of `gslam process`"],
    ),
    "process a log without laser": (
        lambda t: ["process", t["no_laser_mcap"], t["dir"] / "o.mcap"],
        ["has no laser", "SLAM needs laser scans"],
    ),
}


@pytest.fixture(scope="module")
def tiny_more(tiny) -> dict[str, Path]:
    t = dict(tiny)
    (t["dir"] / "empty.txt").write_text("")
    t["carmen_mcap"] = t["dir"] / "carmen.mcap"
    ingest(t["clf"], t["carmen_mcap"])
    t["no_laser_mcap"] = t["dir"] / "no_laser.mcap"
    ingest(write_log(t["dir"] / "no_laser", laser=False), t["no_laser_mcap"])
    return t


@pytest.mark.parametrize("case", REFUSALS, ids=list(REFUSALS))
def test_refusals_name_the_option_and_what_was_expected(tiny_more, case):
    args, fragments = REFUSALS[case]
    args = args(tiny_more)
    before = fingerprint(tiny_more["dir"])
    one_line_refusal(run(*args), *fragments)
    assert fingerprint(tiny_more["dir"]) == before
    assert not (tiny_more["dir"] / "o.mcap").exists()


def test_output_where_nothing_can_be_written_names_the_users_path(tiny):
    target = Path("/sys/gslam-out.mcap")  # sysfs refuses new files, even to root
    try:
        os.close(os.open(target, os.O_CREAT | os.O_WRONLY))
    except OSError:
        pass
    else:
        target.unlink()
        pytest.skip("needs a directory nobody can write in (/sys on Linux); /sys took a new file here")
    before = fingerprint(tiny["dir"])
    line = one_line_refusal(
        run("process", tiny["in"], target, "--no-rrd"), "OUTPUT /sys/gslam-out.mcap", "cannot write"
    )
    assert ".tmp" not in line
    assert fingerprint(tiny["dir"]) == before


# ---- 3. accepted silently before: now noted ---------------------------------------------------------
def test_eval_says_a_result_is_partial_and_withholds_pole_error_without_gps(tmp_path):
    from pipelines.process import process
    from pipelines.run.interrupts import Stopped
    from pipelines.run.runner import RunConfig

    ingest(write_log(tmp_path / "log", gps=False, beacons=True, scans=6), tmp_path / "in.mcap")
    before = fingerprint(tmp_path / "in.mcap")

    def stop_after_two(done, total, *_):
        if done == 2:
            raise Stopped(signal.SIGTERM)

    with pytest.raises(Stopped):
        process(tmp_path / "in.mcap", tmp_path / "r.mcap", None, RunConfig(), stop_after_two)
    text = run("eval", tmp_path / "r.mcap")
    assert text.exit_code == 0, text.output
    first = text.output.splitlines()[0]
    assert first.startswith("note: partial result") and "SIGTERM" in first and "after 2 of 6 scans" in first
    assert "pole map error not computed: the run did not start from GPS" in text.output
    data = json.loads(run("eval", tmp_path / "r.mcap", "--json").output)
    assert data["interrupted"] is True and data["steps"] == 2
    assert data["pole_map_error_m"] is None and any("partial" in n for n in data["notes"])
    assert fingerprint(tmp_path / "in.mcap") == before


# ---- 4. faults: SIGTERM, SIGKILL, stale temporaries ------------------------------------------------
def _start(args: list[str], env_extra: dict[str, str] | None = None) -> subprocess.Popen:
    env = dict(os.environ, GSLAM_PROGRESS_EVERY_S="0.05", GSLAM_PROGRESS="", **(env_extra or {}))
    cmd = [sys.executable, "-m", "pipelines.cli", *map(str, args)]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_progress(proc: subprocess.Popen, timeout_s: float = 120) -> str:
    """Block until the command prints its first progress line (it is then mid-run)."""
    deadline = time.time() + timeout_s
    while time.time() < deadline:
        line = proc.stderr.readline()
        if line.startswith("G-SLAM: "):
            return line
        if proc.poll() is not None:
            break
    raise AssertionError("no progress line from the run")


def test_sigterm_finishes_valid_outputs_marked_interrupted(carpark_mcap, tmp_path):
    from pipelines.evaluation.mcap_info import mcap_info

    before = fingerprint(carpark_mcap)
    out = tmp_path / "r.mcap"
    proc = _start(["process", carpark_mcap, out])
    _wait_for_progress(proc)
    proc.send_signal(signal.SIGTERM)
    time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)  # a second signal during the cleanup does not cut it short
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "interrupted (SIGTERM)" in err and "marked interrupted" in err
    info = mcap_info(out)
    assert info["metadata"]["result"]["interrupted"] is True
    assert 0 < info["metadata"]["result"]["steps"] < 586
    assert out.with_suffix(".rrd").stat().st_size > 0
    assert not list(tmp_path.glob(".*.tmp"))
    assert fingerprint(carpark_mcap) == before


def test_sigkill_leaves_no_final_file_and_the_next_run_removes_its_temporaries(carpark_mcap, tmp_path):
    out = tmp_path / "r.mcap"
    proc = _start(["process", carpark_mcap, out])
    _wait_for_progress(proc)
    proc.kill()
    proc.communicate(timeout=60)
    assert not out.exists() and not out.with_suffix(".rrd").exists()
    temps = sorted(tmp_path.glob(".*.tmp"))
    assert [t.name.split("-")[0] for t in temps] == [f".r.mcap.{proc.pid}", f".r.rrd.{proc.pid}"]
    said = run("info", temps[0])
    one_line_refusal(said, "unfinished temporary file of gslam", str(out), f"process {proc.pid} is no longer running")
    done = run("process", carpark_mcap, out, "--max-scans", "3")
    assert done.exit_code == 0, done.output
    assert out.exists() and not list(tmp_path.glob(".*.tmp"))


# ---- 5. what a user sees ---------------------------------------------------------------------------
def test_progress_off_a_terminal_and_time_per_update(tiny, tmp_path):
    result = run("process", tiny["in"], tmp_path / "o.mcap", "--no-rrd", env={"GSLAM_PROGRESS_EVERY_S": "0"})
    assert result.exit_code == 0, result.output
    assert "G-SLAM: 1/4 scans (25%)" in result.output and "G-SLAM: 4/4 scans (100%)" in result.output
    assert "ms per update (filter, mean)" in result.output and "median" not in result.output


def test_help_shows_bracketed_words_and_defaults():
    text = run("process", "--help").output
    assert "[filter] options and run options" in text
    assert "[default: (30); 1<=x<=4096]" in " ".join(text.split())  # particles: FilterConfig's default
    assert "[options]" in run("sweep", "--help").output


def test_plot_titles_and_legends_inside_the_figure_and_off_the_data(tiny):
    import matplotlib.pyplot as plt

    from pipelines.evaluation.plot import result_figure

    fig = result_figure(tiny["result"], tiny["in"])
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        frame = fig.bbox
        for ax in [a for a in fig.axes if a.get_legend() is not None]:  # the map and the error plot
            for artist in (ax.title, ax.get_legend()):
                box = artist.get_window_extent(renderer)
                assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1
            assert not ax.get_legend().get_window_extent(renderer).overlaps(ax.get_window_extent(renderer))
    finally:
        plt.close(fig)


def test_memory_measurement_runs_and_reports_both_peaks(tiny, capsys):
    from pipelines.bench.memory import main

    assert main([str(tiny["in"]), "--first", "2", "--json", "--no-rrd"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["scans"] == 4 and report["first_scans"] == 2
    assert 0 < report["peak_first_mib"] <= report["peak_all_mib"]
    assert report["ratio"] == pytest.approx(report["peak_all_mib"] / report["peak_first_mib"])
