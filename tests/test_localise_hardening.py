"""`gslam localise` against hostile maps, bad options and signals: map files opened only when they are what
they claim (a map_server YAML's image a regular PGM of bounded size, its fields checked), the likelihood field
bounded before it is allocated, options checked before the first scan, no output over a file the map names,
and SIGINT / SIGTERM keeping the scans done (finished, marked interrupted, exit 130 / 143, no temporary).

The input is a simulated robot's drive in the office world (a bag, ingested); the map is the world's walls
drawn into a map_server PGM; the result maps are written here with only what `gslam localise` reads."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from bagtools import bag_from_robot
from test_reliability import one_line_refusal, run
from worlds import office_world, simulate_robot_loop

from mcaplog import channels as ch
from mcaplog.mcapio import AtomicMcapWriter, McapInput, to_ns
from pipelines.errors import InputError

START = (0.0, -6.0, 0.0)
"""Where `simulate_robot_loop` starts the robot (the world's frame, the map's)."""


def _world_pgm(yaml_path: Path, resolution_m: float = 0.05) -> Path:
    """The office world's walls and pillars drawn into a map_server map: `yaml_path` and its PGM beside it."""
    world = office_world()
    pts = []
    for x0, y0, x1, y1 in world.walls:
        t = np.linspace(0.0, 1.0, max(2, int(math.hypot(x1 - x0, y1 - y0) / 0.01)))
        pts.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    for cx, cy, r in world.poles:
        a = np.linspace(0.0, 2 * math.pi, 200)
        pts.append(np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)]))
    xy = np.vstack(pts)
    lo = xy.min(axis=0) - 1.0
    w, h = np.ceil((xy.max(axis=0) + 1.0 - lo) / resolution_m).astype(int)
    img = np.full((h, w), 254, np.uint8)
    ij = np.floor((xy - lo) / resolution_m).astype(int)
    img[h - 1 - ij[:, 1], ij[:, 0]] = 0
    pgm = yaml_path.with_suffix(".pgm")
    pgm.write_bytes(b"P5\n%d %d\n255\n" % (w, h) + img.tobytes())
    yaml_path.write_text(
        f"image: {pgm.name}\nresolution: {resolution_m}\norigin: [{lo[0]}, {lo[1]}, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    return yaml_path


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> dict[str, Path]:
    """Two laps of the office world (578 scans) as an input MCAP, and the world's map_server map."""
    from ingest import ingest

    d = tmp_path_factory.mktemp("hardening")
    sim = simulate_robot_loop(office_world(), np.random.default_rng(2), laps=2.0)
    ingest(bag_from_robot(sim, d / "robot.bag", "ros1", "topic"), d / "in.mcap")
    return {"dir": d, "in": d / "in.mcap", "yaml": _world_pgm(d / "map.yaml"), "scans": len(sim.t_s)}


def _map_yaml(path: Path, **fields: str) -> Path:
    """A map_server YAML with the given fields (the others valid)."""
    values = {"image": "map.pgm", "resolution": "0.05", "origin": "[0.0, 0.0, 0.0]", "negate": "0",
              "occupied_thresh": "0.65", "free_thresh": "0.196", **fields}  # fmt: skip
    path.write_text("".join(f"{k}: {v}\n" for k, v in values.items()))
    return path


def _fake_result(path: Path, xy: np.ndarray, input_path: Path | None = None) -> Path:
    """A `gslam process` result holding only what a map is read from: one step, its final trajectory and the
    final map's points `xy` (and the input MCAP it names)."""
    w = AtomicMcapWriter(path)
    w.add_metadata("config", {"filter": {}})
    w.add_metadata("result", {"steps": 1})
    if input_path is not None:
        w.add_metadata("input", {"path": str(input_path)})
    ns = to_ns(1.0)
    w.write_proto(ch.SLAM_POSE, ch.pose_in_frame(1.0, 0.0, 0.0, 0.0, ch.MAP_FRAME), ns)
    trajectory = ch.poses_in_frame_bytes(1.0, np.zeros((1, 3)), ch.MAP_FRAME)
    w.write_proto_bytes(ch.SLAM_TRAJECTORY, ch.PosesInFrame, trajectory, ns)
    w.write_proto(ch.SLAM_MAP_FINAL, ch.point_cloud(1.0, np.asarray(xy, float), np.ones(len(xy))), ns)
    w.finish()
    return path


def _nothing_written(d: Path) -> None:
    assert not list(d.glob("o.*")) and not list(d.glob(".*.tmp")), sorted(p.name for p in d.iterdir())


# ---- 1. map files: what they claim, of bounded size ----------------------------------------------------
SECRET = b"root:SECRET-HASH-9f8e7d:19000:0:99999:7:::\ndaemon:*:19000:0:99999:7:::\n"


def _image_cases(d: Path) -> dict[str, str]:
    """`image:` values that are no map image, made in `d`: name -> the value."""
    (d / "secret.pgm").write_bytes(SECRET)  # a regular file named .pgm that holds no image
    os.mkfifo(d / "fifo.pgm")
    (d / "zero.pgm").symlink_to("/dev/zero")
    (d / "dir.pgm").mkdir()
    (d / "header.pgm").write_bytes(b"P5\n640 ten\n255\n" + bytes(64))
    (d / "short.pgm").write_bytes(b"P5\n# a comment\n640 480\n255\n" + bytes(1000))
    (d / "huge.pgm").write_bytes(b"P5 99999 99999 255\n" + bytes(16))
    (d / "plain.pgm").write_bytes(b"P2\n2 2\n255\n0 254\n254 daemon\n")
    return {
        "/etc/shadow": "/etc/shadow",
        "../../../../etc/passwd": "../../../../etc/passwd",
        "/dev/zero": "/dev/zero",
        "a FIFO": "fifo.pgm",
        "a symlink to /dev/zero": "zero.pgm",
        "a directory": "dir.pgm",
        "not a PGM": "secret.pgm",
        "a malformed header": "header.pgm",
        "pixels missing": "short.pgm",
        "99999 x 99999 pixels": "huge.pgm",
        "a plain raster with text": "plain.pgm",
    }


def _unblock_fifo(fifo: Path, after_s: float = 5.0, within_s: float = 300.0) -> threading.Thread:
    """Should the FIFO be opened for reading (it must not be), a writer (from `after_s` on) ends the wait, so
    that the test fails rather than hangs."""

    def write() -> None:
        time.sleep(after_s)
        deadline = time.monotonic() + within_s
        while time.monotonic() < deadline:
            try:
                fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:  # no reader: nobody has opened it (yet)
                time.sleep(0.2)
                continue
            os.write(fd, SECRET)
            os.close(fd)
            return

    t = threading.Thread(target=write, daemon=True)
    t.start()
    return t


def test_a_yaml_image_that_is_no_pgm_file_is_refused_in_one_line_naming_both(drive, tmp_path):
    """/etc/shadow, a path out of the directory, /dev/zero, a FIFO, a device behind a .pgm symlink, a
    directory, a file of other bytes, a malformed or lying header: each refused in one line that names the YAML
    and the image as the YAML gives it, never the file's bytes nor numpy's words; no output."""
    cases = _image_cases(tmp_path)
    _unblock_fifo(tmp_path / "fifo.pgm")
    for what, image in cases.items():
        yaml = _map_yaml(tmp_path / "bad.yaml", image=image)
        said = run("localise", yaml, drive["in"], tmp_path / "o.mcap")
        line = one_line_refusal(said, str(yaml), str(tmp_path / image) if not image.startswith("/") else image)
        for leaked in ("SECRET", "daemon", "root:", "buffer", "invalid literal", "b'"):
            assert leaked not in line, (what, line)
        _nothing_written(tmp_path)
    line = one_line_refusal(run("localise", _map_yaml(tmp_path / "bad.yaml", image="huge.pgm"), drive["in"],
                                tmp_path / "o.mcap"))  # fmt: skip
    assert "99999 x 99999 pixels of 0.05 m, 4999.95 m x 4999.95 m" in line and "1e+10 cells" in line, line


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("resolution", "inf"),
        ("resolution", "1e300"),
        ("resolution", "-1"),
        ("resolution", "0"),
        ("resolution", "nan"),
        ("origin", "[nan, 0.0, 0.0]"),
        ("origin", "[0.0, inf, 0.0]"),
        ("negate", "2"),
        ("occupied_thresh", "1.5"),
        ("occupied_thresh", "nan"),
        ("free_thresh", "-0.1"),
    ],
)
def test_each_yaml_field_is_checked_and_named(drive, tmp_path, field, value):
    """A field out of its range is refused in one line naming the YAML and the field, before the image is
    read and before any scan (today inf and 1e300 m cells, negate 2 and thresholds outside [0, 1] run)."""
    yaml = tmp_path / "map.yaml"
    yaml.write_text(drive["yaml"].read_text().replace("image: map.pgm", f"image: {drive['yaml'].with_suffix('.pgm')}"))
    lines = [ln for ln in yaml.read_text().splitlines() if not ln.startswith(f"{field}:")]
    yaml.write_text("\n".join([*lines, f"{field}: {value}"]) + "\n")
    one_line_refusal(run("localise", yaml, drive["in"], tmp_path / "o.mcap"), str(yaml), field)
    _nothing_written(tmp_path)


def test_the_yaml_itself_must_be_a_small_regular_file(drive, tmp_path):
    """A FIFO named .yaml is not opened; a 100 KB YAML (a valid map padded with comments) is refused by its
    size; a binary one by its encoding: one line each, naming it."""
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    _unblock_fifo(fifo)
    one_line_refusal(run("localise", fifo, drive["in"], tmp_path / "o.mcap"), str(fifo), "FIFO")
    big = tmp_path / "big.yaml"
    text = drive["yaml"].read_text().replace("image: map.pgm", f"image: {drive['yaml'].with_suffix('.pgm')}")
    big.write_text(text + "# padding\n" * 10_000)
    one_line_refusal(run("localise", big, drive["in"], tmp_path / "o.mcap"), str(big), "KiB")
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"image: \xff\xfe\x00map.pgm\n")
    one_line_refusal(run("localise", binary, drive["in"], tmp_path / "o.mcap"), str(binary), "UTF-8")
    _nothing_written(tmp_path)


# ---- 2. bounded allocation ----------------------------------------------------------------------------
def test_a_map_3_km_across_is_refused_before_its_field_is_allocated(drive, tmp_path):
    """Two map points 3 km apart (on a diagonal): the field would be 42550 x 42550 cells (today 1.7 GiB for
    its first array, then the distance transform's). Refused with the map's extent and the cell count, having
    allocated almost nothing; the command says it in one line."""
    from pipelines.localise.maps import load_map

    far = 3000.0 / math.sqrt(2.0)
    result = _fake_result(tmp_path / "far.mcap", np.array([[0.0, 0.0], [far, far]]))
    assert result.stat().st_size < 200_000
    tracemalloc.start()
    try:
        with pytest.raises(InputError) as refused:
            load_map(result)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 50e6, peak
    message = str(refused.value)
    assert "2121.32 m x 2121.32 m" in message and "42550 x 42550" in message and "cells" in message, message
    line = one_line_refusal(run("localise", result, drive["in"], tmp_path / "o.mcap"), str(result), "1e+08")
    assert "spans" in line


# ---- 3. options checked before the first scan ----------------------------------------------------------
@pytest.mark.parametrize(
    ("option", "values"),
    [
        ("--initial-pose", ["nan", "nan", "nan"]),
        ("--initial-pose", ["0", "inf", "0"]),
        ("--initial-sigma", ["-1", "-1"]),
        ("--initial-sigma", ["0.2", "nan"]),
    ],
)
def test_initial_pose_and_sigma_must_be_finite_and_spreads_not_negative(drive, tmp_path, option, values):
    """Refused in one line naming the option and its values, before anything is read or written (today a NaN
    pose runs the whole log, and a negative spread reports "tracking 50 %")."""
    extra = [] if option == "--initial-pose" else ["--initial-pose", *map(str, START)]
    said = run("localise", drive["yaml"], drive["in"], tmp_path / "o.mcap", *extra, option, *values)
    one_line_refusal(said, f"{option} {' '.join(values)}")
    _nothing_written(tmp_path)


# ---- 4. no output over a file the map names -------------------------------------------------------------
def test_no_output_over_the_yamls_image_or_the_input_a_result_names(drive, tmp_path):
    """OUT or --rrd at the YAML's own PGM, OUT at the input MCAP a map result records: refused before any
    work, in one line naming both paths; the files untouched."""
    yaml = _world_pgm(tmp_path / "map.yaml")  # its own copy: were it overwritten, the other tests' map is not
    pgm = yaml.with_suffix(".pgm")
    before = pgm.read_bytes()
    line = one_line_refusal(run("localise", yaml, drive["in"], pgm), "OUT", str(pgm), str(yaml))
    assert "image" in line
    line = one_line_refusal(run("localise", yaml, drive["in"], tmp_path / "o.mcap", "--rrd", pgm), "--rrd")
    assert str(pgm) in line and str(yaml) in line
    assert pgm.read_bytes() == before
    named = tmp_path / "named.mcap"  # the input the map result was computed from (another copy of the drive)
    named.write_bytes(drive["in"].read_bytes())
    walls = np.array([[x, y] for x in np.arange(-8.0, 8.0, 0.05) for y in (-7.5, 8.0)])
    result = _fake_result(tmp_path / "walls.mcap", walls, input_path=named)
    line = one_line_refusal(run("localise", result, drive["in"], named), "OUT", str(named), str(result))
    assert "recorded input" in line
    assert named.read_bytes() == drive["in"].read_bytes()
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*.tmp"))


# ---- 5. signals -----------------------------------------------------------------------------------------
def _signalled(args: list, sig: int, when) -> tuple[int, str]:
    """Run `gslam localise ARGS` in a subprocess, progress lines every 0.05 s, and send it `sig`: once
    `when(done, total)` holds for a progress line; or, `when` a number, after that many seconds; or, `when` a
    directory, as soon as a temporary (`.*.tmp`) appears in it (the outputs are being opened). (exit code,
    stderr)."""
    env = dict(os.environ, GSLAM_PROGRESS_EVERY_S="0.05", GSLAM_PROGRESS="")
    cmd = [sys.executable, "-m", "pipelines.cli", "localise", *map(str, args)]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen = []
    deadline = time.monotonic() + 300
    if isinstance(when, int | float):
        time.sleep(when)
    elif isinstance(when, Path):
        while time.monotonic() < deadline and proc.poll() is None and not list(when.glob(".*.tmp")):
            time.sleep(0.001)
    else:
        while time.monotonic() < deadline:
            line = proc.stderr.readline()
            if not line:
                break
            seen.append(line)
            m = re.match(r"localise: (\d+)/(\d+) scans", line)
            if m and when(int(m.group(1)), int(m.group(2))):
                break
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=300)
    return proc.returncode, "".join(seen) + err


def _robot_rows(rrd: Path) -> int:
    """The scans in a recording: the rows of the robot's arrows (`rerun rrd print`)."""
    from pipelines.outputs.rerun_viewer import rerun_binary

    printed = subprocess.run([rerun_binary(), "rrd", "print", str(rrd)], capture_output=True, text=True, timeout=120)
    assert printed.returncode == 0, printed.stderr[-2000:]
    rows = re.findall(r"with (\d+) rows .*- /world/robot - data columns: \[Arrows2D:colors", printed.stdout)
    return sum(int(r) for r in rows)


def _kept(out: Path, err: str, signame: str) -> int:
    """The scans the interrupted run says it kept, checked against what `out` holds: it reads whole, every
    scan a pose and a state, and its metadata says interrupted by `signame`."""
    from pipelines.evaluation.localisation import read_localisation

    m = re.search(rf"interrupted \({signame}\); wrote {re.escape(str(out))}.* with the (\d+) of (\d+) scans done, "
                  "marked interrupted", err)  # fmt: skip
    assert m, err
    done, total = int(m.group(1)), int(m.group(2))
    assert 0 < done < total, err
    assert len(read_localisation(out).t_s) == done
    assert sum(1 for _ in McapInput(out).messages(["/localise/pose"])) == done
    result = McapInput(out).metadata()["result"]
    assert result["interrupted"] is True and result["scans"] == done and result["error"] == signame, result
    return done


def test_sigint_mid_run_keeps_the_scans_done_marked_interrupted(drive, tmp_path):
    """SIGINT once some scans are done (global localisation, with the recording): exit 130, the result and
    the recording finished with the scans done, the result marked interrupted and as many poses as the
    message says; no temporary. `gslam eval` says it is interrupted (today: nothing kept)."""
    out = tmp_path / "o.mcap"
    code, err = _signalled([drive["yaml"], drive["in"], out], signal.SIGINT, lambda done, total: done >= 30)
    assert code == 130, err
    assert "Traceback" not in err and "internal error" not in err, err
    done = _kept(out, err, "SIGINT")
    assert _robot_rows(out.with_suffix(".rrd")) == done
    assert not list(tmp_path.glob(".*.tmp"))
    said = run("eval", out, "--json")
    assert said.exit_code == 0, said.output
    metrics = json.loads(said.stdout)
    assert metrics["interrupted"] is True and metrics["scans"] == done
    assert any("interrupted (SIGINT)" in n and f"after {done} of {drive['scans']} scans" in n for n in metrics["notes"])


def test_sigterm_mid_run_exits_143_with_the_result_kept(drive, tmp_path):
    out = tmp_path / "o.mcap"
    args = [drive["yaml"], drive["in"], out, "--no-rrd", "--initial-pose", *map(str, START)]
    code, err = _signalled(args, signal.SIGTERM, lambda done, total: done >= 30)
    assert code == 143, err
    _kept(out, err, "SIGTERM")
    assert not out.with_suffix(".rrd").exists() and not list(tmp_path.glob(".*.tmp"))


def test_a_signal_as_the_last_scan_is_reported_keeps_everything_unmarked(drive, tmp_path):
    """SIGINT as the last scan is reported: both outputs finished, whole and not marked interrupted; exit
    130 (today all the work is discarded)."""
    out = tmp_path / "o.mcap"
    args = [drive["yaml"], drive["in"], out, "--initial-pose", *map(str, START)]
    code, err = _signalled(args, signal.SIGINT, lambda done, total: done == total)
    assert code == 130, err
    finished = ("every scan was processed", "after the command had finished", "while gslam exited")
    assert any(f in err for f in finished), err  # where the signal came: the finish, the summary, the exit
    result = McapInput(out).metadata()["result"]
    assert result["interrupted"] is False and result["scans"] == drive["scans"], result
    assert _robot_rows(out.with_suffix(".rrd")) == drive["scans"]
    assert not list(tmp_path.glob(".*.tmp"))


@pytest.mark.parametrize("when", ["as the outputs open", 0.5, 1.5])
def test_a_signal_at_any_moment_leaves_no_temporary(drive, tmp_path, when):
    """SIGINT as soon as the outputs' temporaries appear (today the recording's start follows, and a signal
    there leaves the result's temporary behind), or after a fixed delay (imports, the map, the first scans):
    exit 130, no temporary; at OUT either nothing (stopped before the first scan) or a whole result marked
    interrupted."""
    out = tmp_path / "o.mcap"
    when = tmp_path if when == "as the outputs open" else when
    code, err = _signalled([drive["yaml"], drive["in"], out], signal.SIGINT, when)
    assert code == 130, err
    assert "Traceback" not in err and "internal error" not in err, err
    assert not list(tmp_path.glob(".*.tmp")), sorted(p.name for p in tmp_path.iterdir())
    if out.exists():
        _kept(out, err, "SIGINT")
    else:
        assert not out.with_suffix(".rrd").exists()
