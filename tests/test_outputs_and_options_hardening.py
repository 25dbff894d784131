"""Outputs that are not regular files, `config --dump -o` over a user's file, the ingest beside a direct log,
hostile config files and options: each refused before any work, in one line naming the option or file, and
nothing touched. Devices are never put at risk: the outputs tried are FIFOs and symlinks in tmp_path (one to
/dev/null, which must still be a character device afterwards); anything that would block or spin on the
old code runs in a thread or a subprocess with a deadline."""

from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from test_reliability import one_line_refusal, run

ROOT = Path(__file__).resolve().parents[1]


def _devnull_intact() -> None:
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode), "/dev/null is no longer a character device"


def _carmen_log(path: Path, scans: int = 20, shift: float = 0.0) -> Path:
    """A small CARMEN log: a robot driving along a corridor 2 m wide (`shift` changes its content)."""
    import math

    lines = []
    for i in range(scans):
        x, t = 0.1 * i + shift, 100.0 + 0.2 * i
        ranges = []
        for b in range(180):
            s = math.sin(math.radians(-90 + b))
            ranges.append(min(1.0 / abs(s), 30.0) if abs(s) > 1e-3 else 30.0)
        r = " ".join(f"{v:.3f}" for v in ranges)
        lines.append(f"FLASER 180 {r} {x:.3f} 0 0 {x:.3f} 0 0 {t:.3f} host {t:.3f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def _within(fn: Callable[[], object], seconds: float, unblock: Path | None = None) -> object:
    """`fn()` in a thread; fails the test when it has not returned within `seconds` (a read of a FIFO that
    blocks), then opens the FIFO `unblock` for writing so that the stuck reader sees its end."""
    box: dict[str, object] = {}

    def target() -> None:
        try:
            box["value"] = fn()
        except BaseException as e:  # noqa: BLE001 - handed to the test
            box["error"] = e

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(seconds)
    if thread.is_alive():
        if unblock is not None:
            try:
                os.close(os.open(unblock, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
        pytest.fail(f"still running after {seconds} s (blocked or quadratic)")
    if "error" in box:
        raise box["error"]  # type: ignore[misc]
    return box.get("value")


def _python(code: str, timeout_s: float, memory_gb: float | None = None) -> subprocess.CompletedProcess:
    """Run `code` in a fresh interpreter (killed after `timeout_s`: a test never hangs or spins on)."""

    def limit() -> None:
        if memory_gb is not None:
            import resource

            cap = int(memory_gb * 2**30)
            resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

    try:
        return subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            cwd=ROOT,
            preexec_fn=limit,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"still running after {timeout_s} s")


# ---- 1. an output that exists and is not a regular file is never replaced ---------------------------
OUTPUT_CASES = {
    "config -o FIFO": (lambda t, o: ["config", "--dump", "-o", o], "fifo", "-o"),
    "config -o symlink to /dev/null": (lambda t, o: ["config", "--dump", "-o", o], "devnull", "-o"),
    "export --tum FIFO": (lambda t, o: ["export", t["result"], "--tum", o], "fifo", "--tum"),
    "export --tum symlink to a file (/dev/stdout redirected)": (
        lambda t, o: ["export", t["result"], "--tum", o],
        "file",
        "--tum",
    ),
    "process --rrd symlink to /dev/null": (
        lambda t, o: ["process", t["in"], t["dir"] / "never.mcap", "--rrd", o],
        "devnull",
        "--rrd",
    ),
    "process OUTPUT FIFO": (lambda t, o: ["process", t["in"], o, "--no-rrd"], "fifo", "OUTPUT"),
}


@pytest.mark.parametrize("case", OUTPUT_CASES, ids=list(OUTPUT_CASES))
def test_an_output_that_is_not_a_regular_file_is_refused_and_left_as_it_was(small, tmp_path, case):
    args, kind, label = OUTPUT_CASES[case]
    out = tmp_path / "out.x"
    target = tmp_path / "target.txt"
    target.write_text("kept\n")
    if kind == "fifo":
        os.mkfifo(out)
    else:
        out.symlink_to("/dev/null" if kind == "devnull" else target)
    line = one_line_refusal(run(*args(small, out)), label, str(out), "an output replaces only a regular file")
    assert ("FIFO" in line) if kind == "fifo" else ("symlink" in line), line
    if kind == "fifo":
        assert stat.S_ISFIFO(os.lstat(out).st_mode)
    else:
        assert out.is_symlink() and os.readlink(out) == ("/dev/null" if kind == "devnull" else str(target))
    assert target.read_text() == "kept\n"
    assert not (small["dir"] / "never.mcap").exists()
    _devnull_intact()


def test_the_temporary_files_refuse_to_rename_over_a_fifo_or_a_symlink(tmp_path):
    """The last guard, behind the commands' checks: write_atomic and create_temporary (every writer's
    temporary) refuse a path that is not a regular file, and leave it as it was."""
    from mcaplog.tempfiles import create_temporary, write_atomic

    fifo, link = tmp_path / "pipe", tmp_path / "null"
    os.mkfifo(fifo)
    link.symlink_to("/dev/null")
    for path in (fifo, link):
        with pytest.raises(OSError) as refused:
            write_atomic(path, "text")
        assert str(path) in str(refused.value) and "regular file" in str(refused.value)
        with pytest.raises(OSError):
            create_temporary(path)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and link.is_symlink()
    assert not list(tmp_path.glob(".*.tmp"))
    write_atomic(tmp_path / "plain.txt", "a")  # a regular file, or nothing, is replaced as before
    write_atomic(tmp_path / "plain.txt", "b")
    assert (tmp_path / "plain.txt").read_text() == "b"
    _devnull_intact()


# ---- 2. config --dump -o replaces only a config it wrote ---------------------------------------------
def test_config_dump_never_replaces_a_file_it_did_not_write(small, tmp_path):
    precious = tmp_path / "mine.mcap"
    precious.write_bytes(small["in"].read_bytes())
    notes = tmp_path / "notes.toml"
    notes.write_text("# my own settings\n[filter]\nparticles = 12\n")
    for path in (precious, notes):
        before = path.read_bytes()
        one_line_refusal(run("config", "--dump", "-o", path), "-o", str(path), "gslam config --dump")
        assert path.read_bytes() == before
    mine = tmp_path / "all.toml"
    assert run("config", "--dump", "-o", mine).exit_code == 0
    mine.write_text(mine.read_text().replace("particles = 30", "particles = 12"))  # edited, header kept
    again = run("config", "--dump", "-o", mine)  # a template it wrote is replaced
    assert again.exit_code == 0 and "particles = 30" in mine.read_text(), again.output
    assert "any other existing file" in " ".join(run("config", "--help").output.split())


# ---- 3. the ingest beside a direct log -------------------------------------------------------------------
def test_process_never_replaces_the_ingest_of_another_log(tmp_path):
    mine = _carmen_log(tmp_path / "mine.clf", shift=5.0)
    users = tmp_path / "r.input.mcap"
    assert run("ingest", mine, "-o", users).exit_code == 0  # the user's own ingest of their log
    before = users.read_bytes()
    log = _carmen_log(tmp_path / "corridor.clf")
    line = one_line_refusal(run("process", log, "-o", tmp_path / "r.mcap", "--no-rrd"), "corridor.clf", "mine.clf")
    assert "another log" in line and str(users) in line, line
    assert users.read_bytes() == before and not (tmp_path / "r.mcap").exists()


def test_an_ingest_is_reused_only_for_the_same_content_whatever_the_modification_time(tmp_path):
    from mcaplog.mcapio import McapInput

    log = _carmen_log(tmp_path / "corridor.clf", scans=20)
    out = tmp_path / "r.mcap"
    first = run("process", log, "-o", out, "--no-rrd", "-N", "2")
    assert first.exit_code == 0 and "ingested it into" in first.output, first.output
    same = run("process", log, "-o", out, "--no-rrd", "-N", "2")
    assert same.exit_code == 0 and "using the earlier ingest" in same.output, same.output
    _carmen_log(log, scans=12, shift=1.0)  # another log put in its place, with an older modification time
    os.utime(log, (946684800, 946684800))
    replaced = run("process", log, "-o", out, "--no-rrd", "-N", "2")
    assert replaced.exit_code == 0 and "ingested it into" in replaced.output, replaced.output
    counts = McapInput(tmp_path / "r.input.mcap").metadata()["dataset"]["counts"]
    assert counts["scans"] == 12, counts


def test_a_fifo_at_the_ingest_name_is_refused_without_opening_it(tmp_path):
    from pipelines.cli.direct_input import prepare
    from pipelines.errors import InputError

    log = _carmen_log(tmp_path / "corridor.clf")
    fifo = tmp_path / "q.input.mcap"
    os.mkfifo(fifo)

    def attempt() -> str:
        with pytest.raises(InputError) as refused:
            prepare(log, tmp_path / "q.mcap")
        return str(refused.value)

    message = _within(attempt, 20, unblock=fifo)
    assert "FIFO" in message and str(fifo) in message, message
    cli = subprocess.run(
        [sys.executable, "-m", "pipelines.cli", "process", log, tmp_path / "q.mcap", "--no-rrd"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert cli.returncode == 2 and "FIFO" in cli.stderr and str(fifo) in cli.stderr, cli.stderr
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


# ---- 4. hostile --config files -----------------------------------------------------------------------
def test_a_config_that_is_a_fifo_a_device_or_a_directory_is_refused_unread(tmp_path):
    from pipelines.errors import OptionError
    from pipelines.run.options import run_config

    fifo = tmp_path / "run.toml"
    os.mkfifo(fifo)

    def attempt(path: Path) -> str:
        with pytest.raises(OptionError) as refused:
            run_config(path, [], [])
        return str(refused.value)

    assert "FIFO" in _within(lambda: attempt(fifo), 20, unblock=fifo)
    assert "directory" in attempt(tmp_path)
    # /dev/zero never ends: on a reader that does not check, it would fill the memory (capped here)
    zero = _python(
        "from pathlib import Path\n"
        "from pipelines.run.options import run_config\n"
        "try:\n    run_config(Path('/dev/zero'), [], [])\n"
        "except Exception as e:\n    print(type(e).__name__, e)\n",
        timeout_s=120,
        memory_gb=3,
    )
    assert zero.stdout.startswith("OptionError /dev/zero") and "character device" in zero.stdout, zero


@pytest.mark.parametrize(
    "text",
    ["a = " + "[" * 10_000 + "]" * 10_000 + "\n", "a = " + "{b = " * 3_000 + "1" + "}" * 3_000 + "\n"],
    ids=["lists", "inline tables"],
)
def test_deeply_nested_toml_is_one_line_not_a_recursion_error(small, tmp_path, text):
    cfg = tmp_path / "deep.toml"
    cfg.write_text(text)
    line = one_line_refusal(run("process", small["in"], tmp_path / "o.mcap", "--config", cfg), str(cfg), "nested")
    assert "RecursionError" not in line and len(line) < 300, line


def test_a_million_unknown_keys_are_refused_in_linear_time_listing_a_few(tmp_path):
    """Looking each key's line up by a pass of its own was quadratic: 8 000 keys took 21.5 s. 100 000
    (just under the size bound) now take about a second, and a million are over the bound."""
    some = tmp_path / "some.toml"
    some.write_text("[filter]\n" + "".join(f"k{i}=1\n" for i in range(100_000)))
    million = tmp_path / "million.toml"
    million.write_text("[filter]\n" + "".join(f"k{i}=1\n" for i in range(1_000_000)))
    code = (
        "import sys, time\nfrom pathlib import Path\nfrom pipelines.run.options import run_config\n"
        "for p in sys.argv[1:]:\n"
        "    t = time.monotonic()\n"
        "    try:\n        run_config(Path(p), [], [])\n"
        "    except Exception as e:\n        print(f'{time.monotonic() - t:.2f}', type(e).__name__, e)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, some, million], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    lines = done.stdout.splitlines()
    assert len(lines) == 2, done
    for line in lines:
        seconds, kind, message = line.split(" ", 2)
        assert kind == "OptionError" and float(seconds) < 10 and len(message) < 400, line
    assert "unknown filter option 'k0'" in lines[0] and "99999 more unknown" in lines[0], lines[0]
    assert "million.toml" in lines[1] and "too large" in lines[1], lines[1]


def test_a_refusal_never_echoes_a_huge_value_back(small, tmp_path):
    from pipelines.errors import OptionError
    from pipelines.run.options import parse_set, run_config

    huge = "odom_sigma=[" + ",".join(["1.5"] * 20_000) + "]"
    with pytest.raises(OptionError) as refused:
        run_config(None, [parse_set(huge)], [])
    assert "odom_sigma" in str(refused.value) and len(str(refused.value)) < 400, str(refused.value)[:500]
    cfg = tmp_path / "big.toml"
    cfg.write_text("[filter]\nodom_sigma = [" + ", ".join(["0.5"] * 50_000) + "]\n")
    line = one_line_refusal(run("process", small["in"], tmp_path / "o.mcap", "--config", cfg), "big.toml:2")
    assert len(line) < 400, line[:500]
    with pytest.raises(OptionError) as deep:
        parse_set("odom_sigma=" + "[" * 10_000 + "]" * 10_000)
    assert "nests" in str(deep.value) and len(str(deep.value)) < 300


# ---- 5. options checked before the first scan -----------------------------------------------------------
@pytest.mark.parametrize(
    "setting", ["cell_size_m=1e300", "match_cell_m=1e9", "match_window_margin_m=1e12", "usable_range_m=1e300"]
)
def test_sizes_are_bounded_before_the_run(small, tmp_path, setting):
    name = setting.split("=")[0]
    one_line_refusal(
        run("process", small["in"], tmp_path / "o.mcap", "--set", setting), f"--set {setting}", f"{name} must be in"
    )
    assert not list(tmp_path.iterdir())


def test_contradictory_or_empty_options_are_refused(small, tmp_path):
    out = tmp_path / "o.mcap"
    one_line_refusal(run("process", small["in"], out, "--rrd", tmp_path / "x.rrd", "--no-rrd"), "--rrd", "--no-rrd")
    one_line_refusal(run("process", small["in"], out, "--live-url", ""), "--live-url", "empty")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("url", "said"),
    [
        ("rerun+http://127.0.0.1:70000/proxy", "from 1 to 65535"),
        ("rerun+http://127.0.0.1:0/proxy", "from 1 to 65535"),
        ("rerun+http://::1:9876/proxy", "brackets"),
        ("rerun+http://127.0.0.1:port/proxy", "from 1 to 65535"),
    ],
)
def test_a_malformed_live_url_is_said_naming_the_option(small, tmp_path, url, said):
    one_line_refusal(run("process", small["in"], tmp_path / "o.mcap", "--live-url", url), f"--live-url {url}", said)
    assert not list(tmp_path.iterdir())


def test_an_ipv6_live_url_in_brackets_is_understood():
    from pipelines.outputs.rerun_viewer import parse_live_url

    address = parse_live_url("rerun+http://[::1]:9877/proxy")
    assert (address.host, address.port, address.tls) == ("::1", 9877, False)


class _Endpoint:
    """A TCP endpoint on 127.0.0.1 that is not a Rerun viewer: `plain` answers every connection with an
    HTTP/1.1 400 (a web server), `silent` accepts connections and never says anything."""

    def __init__(self, mode: str) -> None:
        self.server = socket.socket()
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(8)
        self.port = self.server.getsockname()[1]
        self.mode, self.held, self.done = mode, [], threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)

    def _serve(self) -> None:
        self.server.settimeout(0.1)
        while not self.done.is_set():
            try:
                conn, _ = self.server.accept()
            except OSError:
                continue
            if self.mode == "plain":
                conn.recv(4096)
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")
                conn.close()
            else:
                self.held.append(conn)

    def __enter__(self) -> _Endpoint:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.done.set()
        self.thread.join()
        for conn in self.held:
            conn.close()
        self.server.close()


@pytest.mark.parametrize(
    ("mode", "said"), [("plain", "answers plain HTTP (HTTP/1.1 400"), ("silent", "does not answer")]
)
def test_a_live_endpoint_that_is_not_a_rerun_viewer_is_refused_before_the_run(small, tmp_path, mode, said):
    out = tmp_path / "o.mcap"
    with _Endpoint(mode) as endpoint:
        url = f"rerun+http://127.0.0.1:{endpoint.port}/proxy"
        start = time.monotonic()
        result = run("process", small["in"], out, "--live-url", url)
        took = time.monotonic() - start
    line = one_line_refusal(result, f"--live-url {url}", said)
    assert "ERROR" not in result.output and took < 30, (took, line)
    assert not out.exists() and not out.with_suffix(".rrd").exists() and not list(tmp_path.glob(".*.tmp"))
