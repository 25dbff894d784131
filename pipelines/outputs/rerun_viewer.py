"""Where a user looks at a recording: the command that opens one here, and the viewer `--live` streams to."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
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
    """How to open a recording here: the native viewer where there is a screen, else the web viewer
    (`rerun --web-viewer` serves it; open the address it prints in a browser, e.g. through an SSH tunnel)."""
    if has_screen():
        return f"rerun {rrd}"
    return f"rerun --web-viewer {rrd}   (no screen here: it serves the viewer at http://localhost:9090)"


DEFAULT_LIVE_URL = "rerun+http://127.0.0.1:9876/proxy"
"""Where `gslam process --live` streams by default: the port a Rerun viewer listens on."""


def live_viewer(url: str = DEFAULT_LIVE_URL) -> str:
    """Make sure a viewer listens at `url` for `--live`: when nothing does (and `url` is on this machine),
    start one that outlives the run (the native viewer where there is a screen, else `rerun --serve-web`,
    the web viewer). Returns a line saying where to look."""
    from urllib.parse import urlparse

    where = urlparse(url.replace("rerun+", "", 1).replace("rerun://", "http://", 1))
    host, port = where.hostname or "127.0.0.1", where.port or 9876
    with socket.socket() as s:
        s.settimeout(1.0)
        if s.connect_ex((host, port)) == 0:
            return f"streaming live to the Rerun viewer at {url}"
    if host not in ("127.0.0.1", "localhost", "::1"):
        raise ValueError(f"--live-url {url}: no Rerun viewer answers at {host}:{port}")
    screen = has_screen()
    web = 9090 if port_free(9090) else free_port()
    args = [rerun_binary(), "--port", str(port)]
    if not screen:
        args += ["--serve-web", "--web-viewer", "--web-viewer-port", str(web)]
    subprocess.Popen(
        args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, start_new_session=True
    )  # stays open after the run, for the user to look at
    wait_for_port(host, port, 20.0)
    if screen:
        return f"started the Rerun viewer; streaming live to {url}"
    return (
        f"started a Rerun web viewer (no screen here): open http://localhost:{web}/?url={url} in a browser "
        f"(from another machine: ssh -L {web}:localhost:{web} -L {port}:localhost:{port} ...)"
    )


def port_free(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) != 0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
