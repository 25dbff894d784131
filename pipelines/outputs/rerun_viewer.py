"""Where a user looks at a recording: the command that opens one here, and the viewer `--live` streams to.

A `--live-url` is parsed here (`parse_live_url`), not by urllib, so that a bad port or an IPv6 address
without brackets is said in gslam's words, and the endpoint is asked before the run whether it is a gRPC
server, as a Rerun viewer is (`probe_endpoint`): a web server, another HTTP/2 service or a port that never
answers is refused in one line instead of stalling the recording's writer for a minute."""

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

from pipelines.run.live_url import LiveAddress, parse_live_url


def has_screen() -> bool:
    """A native viewer can open a window here."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or sys.platform in ("darwin", "win32")


def rerun_binary() -> str:
    """The `rerun` command of this environment (on PATH, else beside the interpreter)."""
    return shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))


def wait_for_port(host: str, port: int, timeout_s: float) -> bool:
    """Whether something listens at host:port (an IPv4 or IPv6 address, or a name) within `timeout_s`
    (tried every 0.2 s)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            with socket.create_connection((host, port), timeout=1.0):
                return True
        except OSError:
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


PROBE_TIMEOUT_S = 3.0
"""How long an endpoint that accepts the connection is given to answer the probe's gRPC request."""

_PROBE_PATH = b"/gslam.LiveProbe/Probe"
"""The gRPC method the probe asks for: none serves it, and a gRPC server answers an unknown method with
HTTP status 200 and grpc-status UNIMPLEMENTED, where another HTTP/2 server says 404."""
_H2_STATUS = {0x88: 200, 0x89: 204, 0x8A: 206, 0x8B: 304, 0x8C: 400, 0x8D: 404, 0x8E: 500}
"""HPACK's static table: the one byte that encodes `:status` for the common codes."""


def _h2_request(address: LiveAddress) -> bytes:
    """An HTTP/2 client's connection preface, an empty SETTINGS frame and a gRPC request (HEADERS, ending
    the stream) for `_PROBE_PATH`, its header block in plain HPACK (literals, no Huffman coding)."""

    def text(b: bytes) -> bytes:
        return bytes([len(b)]) + b  # a string under 127 bytes, not Huffman-coded

    host = f"[{address.host}]" if ":" in address.host else address.host
    authority = f"{host}:{address.port}".encode("ascii", "replace")[:120]
    block = (
        b"\x83"  # :method POST
        + (b"\x87" if address.tls else b"\x86")  # :scheme https / http
        + b"\x04" + text(_PROBE_PATH)  # :path
        + b"\x01" + text(authority)  # :authority
        + b"\x0f\x10" + text(b"application/grpc")  # content-type (static entry 31)
        + b"\x00" + text(b"te") + text(b"trailers")
    )  # fmt: skip
    headers = len(block).to_bytes(3, "big") + b"\x01\x05" + (1).to_bytes(4, "big")  # END_STREAM | END_HEADERS
    return b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00" + headers + block


def _verdict(frames: list[tuple[int, int, int, bytes]]) -> str | None:
    """What the server's HTTP/2 frames (type, flags, stream, payload) say of it as a gRPC server: None when
    it answered the request with status 200 (or in a form not decoded here), else what it did."""
    for kind, flags, stream, payload in frames:
        if kind == 0x7:  # GOAWAY
            return "speaks HTTP/2 but ends the connection at a gRPC request"
        if kind == 0x3 and stream == 1:  # RST_STREAM
            return "speaks HTTP/2 but refuses a gRPC request"
        if kind == 0x1 and stream == 1:  # HEADERS: the response's status comes first
            at = (1 if flags & 0x8 else 0) + (5 if flags & 0x20 else 0)  # PADDED, PRIORITY
            status = _H2_STATUS.get(payload[at] if len(payload) > at else -1)
            if status is None or status == 200:
                return None
            return f"speaks HTTP/2 but answers a gRPC request with HTTP status {status}, as no gRPC server does"
    return "speaks HTTP/2 but does not answer a gRPC request"


def probe_endpoint(conn: socket.socket, address: LiveAddress, timeout_s: float = PROBE_TIMEOUT_S) -> str | None:
    """Ask the endpoint at the other end of `conn` (connected) whether it is a gRPC server, as a Rerun
    viewer's is: an HTTP/2 request for a method no one serves, which a gRPC server answers with status 200
    (and grpc-status UNIMPLEMENTED). None when it does, else what it did instead ("answers plain HTTP
    (HTTP/1.0 400 ...)", "does not answer within 3 s", ...). The caller owns and closes `conn`."""
    sock = conn
    frames: list[tuple[int, int, int, bytes]] = []
    reply = b""
    deadline = time.monotonic() + timeout_s
    try:
        conn.settimeout(timeout_s)
        if address.tls:
            import ssl

            context = ssl.create_default_context()
            context.set_alpn_protocols(["h2"])
            sock = context.wrap_socket(conn, server_hostname=address.host)
        sock.sendall(_h2_request(address))
        buffer = b""
        while not any(f[0] in (0x1, 0x3, 0x7) for f in frames):
            left = deadline - time.monotonic()
            if left <= 0:
                break
            sock.settimeout(left)
            chunk = sock.recv(4096)
            if not chunk:
                break
            reply = (reply + chunk)[:256]
            buffer += chunk
            if not frames and len(buffer) >= 9 and buffer[3] != 0x4:  # an HTTP/2 server begins with SETTINGS
                break
            while len(buffer) >= 9 and len(buffer) >= 9 + int.from_bytes(buffer[:3], "big"):
                n = int.from_bytes(buffer[:3], "big")
                frames.append(
                    (buffer[3], buffer[4], int.from_bytes(buffer[5:9], "big") & 0x7FFFFFFF, buffer[9 : 9 + n])
                )
                buffer = buffer[9 + n :]
    except TimeoutError:
        pass
    except OSError as e:  # ssl.SSLError is one
        reason = getattr(e, "reason", None) or e.strerror or type(e).__name__
        return f"fails the {'TLS handshake' if address.tls else 'HTTP/2 greeting'} ({reason})"
    if frames and frames[0][0] == 0x4:
        return _verdict(frames)
    if reply.startswith(b"HTTP/"):
        first = reply.split(b"\r\n", 1)[0].decode("ascii", "replace")
        return f"answers plain HTTP ({shown_bytes(first)}), not the HTTP/2 of a Rerun viewer's gRPC server"
    if reply:
        return (
            f"answers {shown_bytes(reply.decode('utf-8', 'replace'))!r}, not the HTTP/2 of a Rerun viewer's gRPC server"
        )
    if time.monotonic() >= deadline:
        return f"accepts the connection but does not answer within {timeout_s:g} s"
    return "closes the connection without answering"


def shown_bytes(text: str, limit: int = 40) -> str:
    """The start of what an endpoint answered, as a message may quote it: printable characters only."""
    text = " ".join("".join(c if c.isprintable() else " " for c in text[: 4 * limit]).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


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
    """Make sure a viewer listens at `url` for `--live`, before the run: one that does (and answers a gRPC
    request as a gRPC server does, `probe_endpoint`) is used as it is (and left alone); when nothing does (and `url` is
    on this machine), one is started (the native viewer where there is a screen, else `rerun --serve-web`,
    the web viewer), for `LiveViewer.end` to stop after the run. A malformed `url`, or an endpoint that
    answers something else or never answers, is an OptionError naming --live-url and what answered."""
    from pipelines.errors import OptionError

    try:
        address = parse_live_url(url)
    except ValueError as e:
        raise OptionError(f"--live-url {url[:100]}: {e}") from None
    host, port = address.host, address.port
    try:
        conn = socket.create_connection((host, port), timeout=1.0)
    except OSError:
        conn = None
    if conn is not None:
        with conn:
            wrong = probe_endpoint(conn, address)
        if wrong is not None:
            raise OptionError(
                f"--live-url {url}: the endpoint at {host}:{port} {wrong}; give the gRPC address of a Rerun "
                f"viewer (start one with: rerun --port {port})"
            )
        return LiveViewer(url, f"streaming live to the Rerun viewer at {url}")
    if host not in ("127.0.0.1", "localhost", "::1"):
        raise OptionError(f"--live-url {url}: no Rerun viewer answers at {host}:{port}")
    screen = has_screen()
    web = 9090 if port_free(9090) else free_port()
    args = [rerun_binary(), "--port", str(port)]
    if host == "::1":  # the viewer listens on IPv4 by default
        args += ["--bind", "::1"]
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
