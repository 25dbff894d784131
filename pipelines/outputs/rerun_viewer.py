"""Where a user looks at a recording: the command that opens one here, and the viewer `--live` streams to."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path


def has_screen() -> bool:
    """A native viewer can open a window here."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or sys.platform in ("darwin", "win32")


def rerun_binary() -> str:
    """The `rerun` command of this environment (on PATH, else beside the interpreter)."""
    return shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))


def wait_for_port(host: str, port: int, timeout_s: float) -> bool:
    """Whether something listens at host:port within `timeout_s` (tried every 0.2 s)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex((host, port)) == 0:
                return True
        time.sleep(0.2)
    return False


def open_command(rrd: Path) -> str:
    """How to open a recording, both ways, the one that works here first: the native viewer where there is
    a screen, else the web viewer (`rerun --web-viewer` serves it; open the address in a browser, e.g.
    through an SSH tunnel)."""
    web = f"rerun --web-viewer {rrd}"
    if has_screen():
        return f"rerun {rrd}   (without a screen: {web}, then open http://localhost:9090)"
    return f"{web}   (no screen here: it serves the viewer at http://localhost:9090; with a screen: rerun {rrd})"


DEFAULT_LIVE_URL = "rerun+http://127.0.0.1:9876/proxy"
"""Where `gslam process --live` streams by default: the port a Rerun viewer listens on."""


STOP_TIMEOUT_S = 10.0
"""How long a viewer started for `--live` is given to end after SIGTERM before it is killed (and again after
SIGKILL)."""


@dataclass
class LiveViewer:
    """The Rerun viewer that `--live` streams to: one found listening (not ours: `process` is None), or one
    started for the run, which `end` stops when the run ends unless asked to leave it running."""

    url: str
    message: str
    """A line saying where to look."""
    process: subprocess.Popen | None = None
    """The viewer started here: the `rerun` command, leader of a process group of its own (it is a Python
    wrapper that runs the viewer binary as its child)."""
    ports: tuple[int, ...] = ()
    """The ports the viewer started here listens on (gRPC, and the web viewer's where there is no screen)."""

    def end(self, keep: bool) -> str | None:
        """At the end of the run (finished, failed or interrupted): stop the viewer started for it, or leave
        it running when `keep`. Returns the line to say, None for a viewer that was not ours."""
        if self.process is None:
            return None
        if keep:
            return (
                f"left the Rerun viewer started for --live running (ports {', '.join(map(str, self.ports))}; "
                f"stop it with: kill -- -{self.process.pid})"
            )
        if self.stop():
            return "stopped the Rerun viewer started for --live (pass --keep-viewer to leave it running)"
        return f"could not stop the Rerun viewer started for --live (process group {self.process.pid})"

    def stop(self, timeout_s: float = STOP_TIMEOUT_S) -> bool:
        """End the viewer started here and everything it started (its process group): SIGTERM, and SIGKILL
        for what is left after `timeout_s`. Returns whether none of them runs any more and its ports are
        free (a listening socket closes with its process)."""
        if self.process is None:
            return True
        group = self.process.pid  # start_new_session: the group's id is the leader's pid
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(group, sig)
            except ProcessLookupError:
                pass
            deadline = time.monotonic() + timeout_s
            while True:
                self.process.poll()  # reaps the leader once it has ended
                gone = not running_in_group(group)
                if gone or time.monotonic() > deadline:
                    break
                time.sleep(0.05)
            if gone:
                break
        return gone and all(wait_port_free(port, timeout_s) for port in self.ports)


def running_in_group(group: int) -> list[int]:
    """The processes of process group `group` still running (ended ones not yet reaped by their parent are
    left out): read from /proc where there is one, else whether the group takes a signal."""
    proc = Path("/proc")
    if not (proc / "self" / "stat").exists():
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            return []
        except PermissionError:
            pass
        return [group]
    found = []
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # ended meanwhile
            continue
        state, _, pgrp = stat[stat.rindex(")") + 2 :].split()[:3]  # after "pid (command) "
        if int(pgrp) == group and state not in ("Z", "X"):
            found.append(int(entry.name))
    return found


def wait_port_free(port: int, timeout_s: float) -> bool:
    """Whether nothing listens at 127.0.0.1:`port` within `timeout_s` (tried every 0.05 s)."""
    deadline = time.monotonic() + timeout_s
    while not port_free(port):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def live_viewer(url: str = DEFAULT_LIVE_URL) -> LiveViewer:
    """Make sure a viewer listens at `url` for `--live`: one that does is used as it is (and left alone);
    when nothing does (and `url` is on this machine), one is started (the native viewer where there is a
    screen, else `rerun --serve-web`, the web viewer), for `LiveViewer.end` to stop after the run."""
    from urllib.parse import urlparse

    where = urlparse(url.replace("rerun+", "", 1).replace("rerun://", "http://", 1))
    host, port = where.hostname or "127.0.0.1", where.port or 9876
    with socket.socket() as s:
        s.settimeout(1.0)
        if s.connect_ex((host, port)) == 0:
            return LiveViewer(url, f"streaming live to the Rerun viewer at {url}")
    if host not in ("127.0.0.1", "localhost", "::1"):
        raise ValueError(f"--live-url {url}: no Rerun viewer answers at {host}:{port}")
    screen = has_screen()
    web = 9090 if port_free(9090) else free_port()
    args = [rerun_binary(), "--port", str(port)]
    if not screen:
        args += ["--serve-web", "--web-viewer", "--web-viewer-port", str(web)]
    process = start_viewer(args)
    wait_for_port(host, port, 20.0)
    if screen:
        return LiveViewer(url, f"started the Rerun viewer; streaming live to {url}", process, (port,))
    message = (
        f"started a Rerun web viewer (no screen here): open http://localhost:{web}/?url={url} in a browser "
        f"(from another machine: ssh -L {web}:localhost:{web} -L {port}:localhost:{port} ...)"
    )
    return LiveViewer(url, message, process, (port, web))


def start_viewer(args: list[str]) -> subprocess.Popen:
    """Start `args` (a `rerun` command) in a session of its own: a Ctrl-C at the terminal reaches only the
    run, which then stops it, and its process group holds the `rerun` wrapper and the viewer binary
    together for `LiveViewer.stop`."""
    return subprocess.Popen(
        args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, start_new_session=True
    )


def port_free(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) != 0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
