"""Hostile input and signals: one test per class of hole, each asserting the exit code, the message, the
untouched inputs, and what stands at the final path. The security cases: predictable temporaries opened
through symlinks, the working directory on the writer's import path, a recorded input path trusted and
echoed, an unbounded chunk."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_reliability import fingerprint, one_line_refusal, run, write_log

from ingest import ingest


def _cli(args: list, env_extra: dict[str, str] | None = None, **kw) -> subprocess.Popen:
    env = dict(os.environ, GSLAM_PROGRESS_EVERY_S="0.05", GSLAM_PROGRESS="", **(env_extra or {}))
    cmd = [sys.executable, "-m", "pipelines.cli", *map(str, args)]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


# ---- 1. inputs destroyed ------------------------------------------------------------------------
def test_export_refuses_to_write_over_the_input_it_names_or_the_pgm_beside_its_yaml(small, tmp_path):
    before = fingerprint(small["in"], small["result"])
    cases = [
        (["--tum", small["in"]], ["--tum", "INPUT (named in RESULT)"]),
        (["--map", small["in"], "--input", small["in"]], ["--map", "is the input"]),
        (["--occupancy", small["in"]], ["--occupancy", "is the input"]),
        (["--occupancy", small["result"].with_suffix(".yaml")], ["the PGM beside --occupancy", "RESULT"]),
    ]
    for extra, fragments in cases:
        if "RESULT" in fragments:  # the PGM beside the YAML is the result itself
            res = small["dir"] / "r.pgm"
            res.write_bytes(small["result"].read_bytes())
            said = run("export", res, "--occupancy", small["dir"] / "r.yaml")
            res.unlink()
        else:
            said = run("export", small["result"], *extra)
        one_line_refusal(said, *fragments)
    assert fingerprint(small["in"], small["result"]) == before


def test_sweep_refuses_results_over_its_spec_and_options_it_would_ignore(small, tmp_path):
    spec = tmp_path / "results.md"
    spec.write_text(f'inputs = ["{small["in"]}"]\n')
    before = fingerprint(spec)
    one_line_refusal(run("sweep", spec, "-o", tmp_path), "the sweep's results.md", "is the input SPEC")
    assert fingerprint(spec) == before
    ignored = tmp_path / "ignored.toml"
    ignored.write_text(f'inputs = ["{small["in"]}"]\n[options]\nparticles = [3]\n')
    one_line_refusal(run("sweep", ignored, "-o", tmp_path / "out"), "ignored.toml:3", "particles", "top-level")
    assert not (tmp_path / "out").exists()


# ---- 2. no corrupt file at a final path -----------------------------------------------------------
def test_a_write_that_fails_mid_run_leaves_nothing_at_the_final_paths_and_names_them(carpark_mcap, tmp_path):
    """Files limited to 300 kB (RLIMIT_FSIZE: writes beyond fail, as on a full disk): both writers fail,
    the error names the user's path, no temporary and no partial file is left."""

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, 300_000))

    out = tmp_path / "r.mcap"
    proc = _cli(["process", carpark_mcap, out, "--max-scans", "300"], preexec_fn=limit)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 2, err
    last = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert len(last) == 1 and ("r.rrd" in last[0] or "r.mcap" in last[0]) and ".tmp" not in last[0], err
    assert not out.exists() and not out.with_suffix(".rrd").exists()
    assert not list(tmp_path.glob(".*.tmp"))


# ---- 3. finished work kept, options checked first ---------------------------------------------------
def test_a_signal_after_the_last_scan_waits_for_both_outputs(carpark_mcap, tmp_path):
    """SIGINT while the occupancy grid is built (every scan done): both outputs finished, complete, not
    marked interrupted; exit 130."""
    from pipelines.evaluation.mcap_info import mcap_info

    out = tmp_path / "r.mcap"
    proc = _cli(["process", carpark_mcap, out, "--occupancy"])
    deadline = time.time() + 300
    while time.time() < deadline:
        line = proc.stderr.readline()
        if "586/586" in line or proc.poll() is not None:
            break
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err
    finished = "every scan was processed" in err or "after the command had finished" in err  # where it came
    assert finished and "Traceback" not in err, err
    meta = mcap_info(out)["metadata"]["result"]
    assert meta["interrupted"] is False and meta["steps"] == 586
    assert out.with_suffix(".rrd").stat().st_size > 10_000
    assert not list(tmp_path.glob(".*.tmp"))


def test_deferred_signals_wait_for_the_block_and_a_quick_second_one_aborts():
    from pipelines.run import interrupts

    interrupts.reset()
    previous = signal.signal(signal.SIGINT, interrupts._handler)
    try:
        finished = False
        with pytest.raises(interrupts.Stopped):
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
                finished = True
        assert finished  # the block ran to its end, then the signal was raised
        interrupts.reset()
        reached = False
        with pytest.raises(interrupts.Stopped):
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
                os.kill(os.getpid(), signal.SIGINT)  # within ABORT_WITHIN_S: aborts the block
                time.sleep(0.05)
                reached = True
        assert not reached
    finally:
        signal.signal(signal.SIGINT, previous)
        interrupts.reset()


def test_a_bad_run_option_in_toml_and_too_many_threads_are_refused_before_the_run(small, tmp_path):
    cfg = tmp_path / "run.toml"
    cfg.write_text("occupancy_resolution_m = 0\n")
    one_line_refusal(run("process", small["in"], tmp_path / "o.mcap", "--config", cfg), "occupancy_resolution_m")
    one_line_refusal(run("process", small["in"], tmp_path / "o.mcap", "--threads", "100000"), "--threads")
    assert not list(tmp_path.glob("o.*")) and not list(tmp_path.glob(".*.tmp"))


# ---- 4. signals, hangs, children ---------------------------------------------------------------------
@pytest.mark.parametrize("after_s", [0.05, 0.2, 0.5])
def test_a_signal_at_start_up_exits_130_without_a_traceback(carpark_mcap, tmp_path, after_s):
    proc = _cli(["process", carpark_mcap, tmp_path / "r.mcap"])
    time.sleep(after_s)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert not list(tmp_path.glob(".*.tmp"))
    out = tmp_path / "r.mcap"
    if out.exists():  # the signal came once the run had begun: both outputs finished, marked interrupted
        from pipelines.evaluation.mcap_info import mcap_info

        assert mcap_info(out)["metadata"]["result"]["interrupted"] is True
        assert (tmp_path / "r.rrd").stat().st_size > 0
    else:  # before: nothing at either final path
        assert not (tmp_path / "r.rrd").exists()


@pytest.mark.parametrize(
    "at",
    [
        "mcaplog/tempfiles.py:create_temporary:return:1",  # the result MCAP's temporary, not yet its writer's
        "mcaplog/tempfiles.py:temporary_for:return:1",  # the recording's temporary, not yet in its writer
        "pipelines/process.py:_open:return",  # outputs open, the run's loop not yet entered
        "pipelines/process.py:_run_steps:call",
    ],
)
def test_a_signal_between_a_temporary_and_its_writer_leaves_nothing(carpark_mcap, tmp_path, at):
    """The windows a timed signal (above) hits one run in many: the signal sent at an exact point
    (tests/signal_at.py). Exit 130, one line, nothing at the final paths, no temporary left."""
    env = dict(os.environ, SIGNAL_AT=at, GSLAM_PROGRESS="")
    script = Path(__file__).with_name("signal_at.py")
    proc = subprocess.run(
        [sys.executable, script, "gslam", "process", carpark_mcap, tmp_path / "r.mcap", "--max-scans", "20"],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 130, proc.stderr
    assert "Traceback" not in proc.stderr and "Exception ignored" not in proc.stderr, proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == "interrupted (SIGINT)", proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_stalled_rerun_writer_is_killed_and_the_result_mcap_kept(carpark_mcap, tmp_path):
    out = tmp_path / "r.mcap"
    proc = _cli(["process", carpark_mcap, out, "--max-scans", "200"], {"GSLAM_WRITER_TIMEOUT_S": "3"})
    deadline = time.time() + 60
    while not _children(proc.pid) and time.time() < deadline:
        time.sleep(0.02)
    (writer,) = _children(proc.pid)
    os.kill(writer, signal.SIGSTOP)
    try:
        _, err = proc.communicate(timeout=120)
    finally:
        try:
            os.kill(writer, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert proc.returncode == 2, err
    assert "stopped answering" in err and "r.rrd" in err
    assert out.stat().st_size > 0 and not out.with_suffix(".rrd").exists()
    assert not list(tmp_path.glob(".*.tmp"))


def test_killing_a_sweep_ends_its_workers(carpark_mcap, tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text(f'inputs = ["{carpark_mcap}"]\nseeds = [0, 1]\n')
    proc = _cli(["sweep", spec, "-o", tmp_path / "out", "--workers", "2"])
    deadline = time.time() + 60
    while len(workers := _children(proc.pid)) < 2 and time.time() < deadline:
        time.sleep(0.1)
    assert workers, "no worker started"
    time.sleep(1.0)
    workers = _children(proc.pid)
    proc.kill()
    proc.communicate(timeout=30)
    deadline = time.time() + 20
    while any(Path(f"/proc/{w}").exists() and "Z" not in _state(w) for w in workers) and time.time() < deadline:
        time.sleep(0.1)
    assert not [w for w in workers if Path(f"/proc/{w}").exists() and "Z" not in _state(w)]


def _state(pid: int) -> str:
    try:
        raw = Path(f"/proc/{pid}/stat").read_text()
        return raw[raw.rindex(")") + 2]
    except (OSError, ValueError):
        return "Z"


def test_fifos_and_devices_are_refused_not_read(tmp_path):
    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    one_line_refusal(run("info", fifo), "FIFO", "not a regular file")
    one_line_refusal(run("ingest", "/dev/zero", "--format", "carmen", "-o", tmp_path / "z.mcap"), "device")
    assert not (tmp_path / "z.mcap").exists()


# ---- 5. security ----------------------------------------------------------------------------------
def test_a_symlink_planted_at_a_temporary_name_is_never_written_through(small, tmp_path, monkeypatch):
    """The name the code once used (`.NAME.PID.tmp`) and the next random name are both planted
    as symlinks to a victim file: export writes its output and the victim is untouched."""
    import secrets

    from mcaplog import tempfiles

    victim = tmp_path / "victim"
    victim.write_text("precious\n")
    out = tmp_path / "t.tum"
    (tmp_path / f".t.tum.{os.getpid()}.tmp").symlink_to(victim)
    real = secrets.token_hex
    calls = iter(range(1000))
    # every second draw is the planted name: each creation first meets the symlink there
    monkeypatch.setattr(secrets, "token_hex", lambda n: "aaaaaaaaaaaa" if next(calls) % 2 == 0 else real(n))
    planted = tmp_path / f".t.tum.{os.getpid()}-{tempfiles._own_start()}-aaaaaaaaaaaa.tmp"
    planted.symlink_to(victim)
    said = run("export", small["result"], "--tum", out)
    assert said.exit_code == 0, said.output
    assert victim.read_text() == "precious\n" and out.read_text().startswith("# timestamp")
    assert planted.is_symlink()  # not ours: left alone


def test_the_stale_sweep_removes_only_files_it_can_prove_are_its_own_dead_processes(tmp_path):
    from mcaplog.tempfiles import create_temporary, describe_temporary, process_start

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)
    parent, parent_start = os.getppid(), process_start(os.getppid())
    out = tmp_path / "r.mcap"
    stale = tmp_path / f".r.mcap.{dead_pid}-123-0123456789ab.tmp"
    live = tmp_path / f".r.mcap.{parent}-{parent_start}-0123456789ab.tmp"
    reused = tmp_path / f".r.mcap.{parent}-{(parent_start or 0) + 1}-0123456789ab.tmp"  # same id, other process
    link = tmp_path / f".r.mcap.{dead_pid}-123-ba9876543210.tmp"
    other = tmp_path / f".other.mcap.{dead_pid}-123-0123456789ab.tmp"
    for p in (stale, live, reused, other):
        p.write_bytes(b"")
    link.symlink_to(tmp_path / "elsewhere")
    assert describe_temporary(stale).alive is False and describe_temporary(live).alive is True
    fd, mine = create_temporary(out)
    os.close(fd)
    assert mine.name.startswith(f".r.mcap.{os.getpid()}-") and mine.stat().st_size == 0
    assert not stale.exists() and not reused.exists()
    assert live.exists() and other.exists() and link.is_symlink()


def test_a_module_in_the_working_directory_is_not_imported_by_the_writer(carpark_mcap, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    marker = tmp_path / "imported"
    (work / "numpy.py").write_text(f"open({str(marker)!r}, 'w').write('x')\nraise SystemExit(3)\n")
    gslam = Path(sys.executable).with_name("gslam")  # the installed command (python -m would put cwd first)
    cmd = [gslam, "process", carpark_mcap, tmp_path / "r.mcap", "--max-scans", "20"]
    proc = subprocess.Popen(list(map(str, cmd)), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=work)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert not marker.exists() and (tmp_path / "r.rrd").stat().st_size > 0


def test_a_recorded_input_path_is_checked_and_never_echoed(small, tmp_path):
    """A result whose recorded input is a secret text file, a FIFO, or another log at the same path."""
    import json

    from mcap.reader import make_reader
    from mcap.writer import Writer

    def with_input(path: Path, fingerprint_of: Path | None) -> Path:
        """A copy of the small result whose metadata names `path` as its input."""
        out = tmp_path / f"r-{path.name}.mcap"
        with open(small["result"], "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
            f.seek(0)
            msgs = list(make_reader(f).iter_messages())
        entry = json.loads(meta["input"]["fingerprint"]) if fingerprint_of is None else None
        meta["input"]["path"] = json.dumps(str(path))
        if fingerprint_of is not None:
            from pipelines.run.recorded_input import fingerprint as fp

            entry = fp(fingerprint_of)
        meta["input"]["fingerprint"] = json.dumps(entry)
        with open(out, "wb") as g:
            w = Writer(g)
            w.start()
            ids = {}
            for sid, s in summary.schemas.items():
                ids[sid] = w.register_schema(s.name, s.encoding, s.data)
            chans = {
                cid: w.register_channel(c.topic, c.message_encoding, ids.get(c.schema_id, 0), c.metadata)
                for cid, c in summary.channels.items()
            }
            for _, channel, m in msgs:
                w.add_message(chans[channel.id], m.log_time, m.data, m.publish_time, m.sequence)
            for name, values in meta.items():
                w.add_metadata(name, values)
            w.finish()
        return out

    secret = tmp_path / "shadow"
    secret.write_text("root:SECRETHASH:19000:0:99999:7:::\n")
    said = run("eval", with_input(secret, None))
    line = one_line_refusal(said, "not the one the run read")
    assert "SECRET" not in line and "root:" not in line
    fifo = tmp_path / "fifo.mcap"
    os.mkfifo(fifo)
    one_line_refusal(run("eval", with_input(fifo, None)), "not a regular file")
    other = tmp_path / "other.mcap"
    ingest(write_log(tmp_path / "other", scans=6), other)
    one_line_refusal(run("eval", with_input(other, small["in"])), "not the one the run read")
    assert run("eval", with_input(small["in"], small["in"])).exit_code == 0


def test_a_chunk_claiming_a_huge_size_is_refused_before_it_is_decompressed(small, tmp_path):
    from mcap.reader import make_reader

    data = bytearray(small["result"].read_bytes())
    with open(small["result"], "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    for chunk in chunks:  # each chunk record now claims 1 GiB of content (its index still the truth)
        field = chunk.chunk_start_offset + 9 + 16  # opcode, length, start and end times: uncompressed_size
        data[field : field + 8] = (1 << 30).to_bytes(8, "little")
    bad = tmp_path / "bomb.mcap"
    bad.write_bytes(bytes(data))
    line = one_line_refusal(run("eval", bad, "--reference", small["in"]), "decompress", "256 MiB")
    assert "bomb.mcap" in line


def test_a_log_given_the_wrong_format_and_a_symlink_loop_output_are_refused_in_one_line(small, tmp_path):
    import gzip

    clf = tmp_path / "x.clf.gz"
    clf.write_bytes(gzip.compress(b"FLASER 3 1.0 1.0 1.0 0 0 0 0 0 0 1.0 h 1.0\n"))
    one_line_refusal(run("ingest", clf, "--format", "rosbag", "-o", tmp_path / "o.mcap"), "not a readable ROS bag")
    loop = tmp_path / "loop.mcap"
    loop.symlink_to(loop)
    one_line_refusal(run("process", small["in"], loop), "OUTPUT", "symlink loop")


# ---- 6. CARMEN ingest streams ------------------------------------------------------------------------
def _carmen_log(path: Path, scans: int) -> Path:
    """A CARMEN log of `scans` FLASER lines of 361 beams (about 2.3 kB each) and as many ODOM lines."""
    beams = " ".join(f"{2.0 + 0.01 * (b % 50):.2f}" for b in range(361))
    with open(path, "w") as f:
        for i in range(scans):
            t = 1.0 + 0.1 * i
            f.write(f"ODOM {0.01 * i:.3f} 0 0 0.1 0 0 {t - 0.05:.3f} host {t - 0.05:.3f}\n")
            f.write(f"FLASER 361 {beams} {0.01 * i:.3f} 0 0 {0.01 * i:.3f} 0 0 {t:.3f} host {t:.3f}\n")
    return path


def _peak_rss_mib(args: list) -> float:
    proc = subprocess.Popen([sys.executable, "-m", "pipelines.cli", *map(str, args)], stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    assert proc.returncode == 0
    return usage.ru_maxrss / 1024


def test_carmen_ingest_memory_is_flat_in_the_logs_length(tmp_path):
    small = _carmen_log(tmp_path / "small.clf", 500)
    large = _carmen_log(tmp_path / "large.clf", 15_000)  # 29 MB of text
    peak_small = _peak_rss_mib(["ingest", small, "-o", tmp_path / "small.mcap"])
    peak_large = _peak_rss_mib(["ingest", large, "-o", tmp_path / "large.mcap"])
    assert large.stat().st_size > 25e6
    assert peak_large - peak_small < 40, (peak_small, peak_large)


def _sydney_log(directory: Path, scans: int) -> Path:
    """A Sydney text log: `scans` LASER.txt and INTENSITY.txt lines of 361 beams (about 2 kB each), DRS
    at 40 Hz and GPS at 5 Hz over the same time."""
    directory.mkdir()
    beams = ",".join(f"{2.0 + 0.01 * (b % 50):.2f}" for b in range(361))
    codes = ",".join("0" for _ in range(361))
    with open(directory / "LASER.txt", "w") as laser, open(directory / "INTENSITY.txt", "w") as inten:
        for i in range(scans):
            laser.write(f"{1.0 + 0.2 * i:.3f},{beams}\n")
            inten.write(f"{1.0 + 0.2 * i:.3f},{codes}\n")
    with open(directory / "DRS.txt", "w") as f:
        f.writelines(f"{1.0 + 0.025 * i:.3f},2.0,0.01\n" for i in range(8 * scans))
    with open(directory / "GPS.txt", "w") as f:
        f.writelines(f"{1.0 + 0.2 * i:.3f},{0.4 * i:.2f},0.0\n" for i in range(scans))
    return directory


def test_sydney_text_ingest_memory_is_flat_in_the_logs_length(tmp_path):
    small = _sydney_log(tmp_path / "small", 300)
    large = _sydney_log(tmp_path / "large", 10_000)  # 27 MB of text
    size = sum(p.stat().st_size for p in large.iterdir())
    peak_small = _peak_rss_mib(["ingest", small, "-o", tmp_path / "small.mcap"])
    peak_large = _peak_rss_mib(["ingest", large, "-o", tmp_path / "large.mcap"])
    assert size > 25e6
    assert peak_large - peak_small < 40, (peak_small, peak_large)
    from mcaplog import channels as ch
    from pipelines.evaluation.mcap_info import mcap_info

    assert mcap_info(tmp_path / "large.mcap")["channels"][ch.LASER] == 10_000


@pytest.mark.parametrize("kind", ["rosbag1-bz2", "rosbag1-lz4", "rosbag2-mcap-zstd", "rosbag2-message-zstd"])
def test_a_bag_chunk_that_expands_to_a_gibibyte_is_refused_within_the_bound(kind):
    """rosbags decompresses chunks whole and without a limit; after `ingest.bag_limits.install` (done before
    every bag is opened) its decompressors stop at the bound: a 1 GiB bomb of a few kB is refused, and no
    more than the bound is ever allocated."""
    import bz2
    import tracemalloc

    import lz4.frame
    from rosbags.rosbag1 import reader as rosbag1_reader
    from rosbags.rosbag2 import reader as rosbag2_reader
    from rosbags.rosbag2 import storage_mcap

    from ingest.bag_limits import STEP_BYTES, ExpandsTooFar, _zstd_module, install
    from mcaplog.mcapio import MAX_CHUNK_BYTES

    install()
    zstd = _zstd_module()
    gib = 1 << 30
    block = bytes(64 << 20)
    if kind == "rosbag1-bz2":
        c = bz2.BZ2Compressor(1)
        bomb = b"".join(c.compress(block) for _ in range(gib // len(block))) + c.flush()
        decompress = rosbag1_reader.decompressors["bz2"]
    elif kind == "rosbag1-lz4":
        c = lz4.frame.LZ4FrameCompressor()
        bomb = c.begin() + b"".join(c.compress(block) for _ in range(gib // len(block))) + c.flush()
        decompress = rosbag1_reader.decompressors["lz4"]
    else:
        c = zstd.ZstdCompressor()
        bomb = b"".join(c.compress(block) for _ in range(gib // len(block))) + c.flush()
        if kind == "rosbag2-mcap-zstd":
            with pytest.raises(ExpandsTooFar, match="claims"):  # the stated size, checked first
                storage_mcap.DECOMPRESSORS["zstd"](bomb, gib)

            def decompress(data):  # a chunk that states a small size and expands beyond it
                return storage_mcap.DECOMPRESSORS["zstd"](data, 1 << 20)
        else:
            decompress = rosbag2_reader.zstd.decompress
    assert len(bomb) < 20 << 20
    tracemalloc.start()
    try:
        with pytest.raises(ExpandsTooFar, match="expands beyond 256 MiB"):
            decompress(bomb)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MAX_CHUNK_BYTES + 3 * STEP_BYTES, peak  # the bound, the piece being made and one before
    small = {"rosbag1-bz2": bz2.compress, "rosbag1-lz4": lz4.frame.compress}.get(kind, zstd.compress)
    assert decompress(small(b"a scan" * 1000)) == b"a scan" * 1000  # a real chunk still reads
