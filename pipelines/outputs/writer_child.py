"""Output files written by processes of their own, so that encoding and writing them runs on a core the
filter leaves idle (between its updates the filter is one Python thread) instead of in the filter's.

Parent side, `WriterChild`: starts `python -P -m MODULE` (the working directory off its import path),
sends it pickled commands through a queue and a sender thread (the filter never waits on the pipe),
reads its one-line JSON replies. Child side, `serve`: reads the commands and calls the handler's
methods. Commands: ("open", ...) first (replied to), then any of the handler's own, then ("finish", ...)
(replied to, with the process's peak memory and processor time) or ("abort",). When its input ends
without either (the caller was killed) the handler's `close` keeps what was received. The file is always
the caller's temporary: the caller renames it after "finish".
This module imports only the standard library, so the child writers stay small.
"""

from __future__ import annotations

import json
import os
import pickle
import queue
import resource
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

from pipelines.errors import OutputError


def _environment() -> dict[str, str]:
    """This process's environment, with `pipelines` importable by the child writer however it was, and
    no relative entry on its import path (an empty or relative PYTHONPATH entry is the working directory)."""
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    user = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and os.path.isabs(p)]
    env["PYTHONPATH"] = os.pathsep.join([root, *user])
    env.pop("PYTHONSTARTUP", None)
    return env


def python_command(module: str) -> list[str]:
    """`python -P -m module`: -P keeps the working directory off the child's import path, so a `numpy.py`
    (or any module) lying where gslam is run is never imported by the child."""
    return [sys.executable, "-P", "-m", module]


STALL_TIMEOUT_S = 60.0
"""A child writer that takes no input and gives no reply for this long is killed
(`GSLAM_WRITER_TIMEOUT_S` sets another bound)."""


class WriterChild:
    """A child writer for the output `path`, described to the user as `what` in its errors."""

    def __init__(self, module: str, what: str, path: Path, open_command: tuple | None = None) -> None:
        """Start `python -m module`; `open_command` now, or later with `open` (until then only `abort`)."""
        self.what = what
        self.path = Path(path)
        self.peak_rss_mb = float("nan")
        """The child writer's peak resident memory (MB), known after `finish`."""
        self.cpu_s = float("nan")
        """The child writer's processor time (user + system, s), known after `finish`."""
        self.proc = subprocess.Popen(
            python_command(module),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            start_new_session=True,  # a Ctrl-C at the terminal reaches the caller, which then finishes it
            env=_environment(),
        )
        self.stall_timeout_s = float(os.environ.get("GSLAM_WRITER_TIMEOUT_S", STALL_TIMEOUT_S))
        self._progress_at = time.monotonic()
        self._queue: queue.Queue[tuple | None] = queue.Queue()
        self._send_error: OSError | None = None
        self._sender = threading.Thread(target=self._send_loop, name=f"{module}-sender", daemon=True)
        self._sender.start()
        if open_command is not None:
            self.open(open_command)

    def open(self, open_command: tuple) -> None:
        """Have the writer open its file: the handler's arguments."""
        self.send(("open", *open_command))

    def _send_loop(self) -> None:
        while (command := self._queue.get()) is not None:
            if self._send_error is not None:
                continue  # the writer is gone: drop the rest, `finish` says why
            try:
                pickle.dump(command, self.proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
                self.proc.stdin.flush()
                self._progress_at = time.monotonic()
            except OSError as e:  # BrokenPipeError: the writer stopped
                self._send_error = e
        try:
            self.proc.stdin.close()
        except OSError:
            pass

    def send(self, command: tuple) -> None:
        self._queue.put(command)

    def _wait(self, done: Callable[[], bool]) -> None:
        """Wait until `done()`, in short steps (signals are handled meanwhile), while the writer makes
        progress: after `stall_timeout_s` without any (a writer stopped, e.g. by SIGSTOP, or hung) it is
        killed and OutputError says so."""
        while not done():
            if time.monotonic() - self._progress_at > self.stall_timeout_s:
                self.proc.kill()
                self.proc.wait()
                raise OutputError(
                    f"{self.path}: the writer of {self.what} stopped answering for {self.stall_timeout_s:g} s "
                    "and was killed"
                )
            time.sleep(0.02)

    def _close_input(self) -> None:
        """Send what is queued, close the writer's input and wait for the sender (not the writer)."""
        if self._sender.is_alive():
            self._queue.put(None)
            self._wait(lambda: not self._sender.is_alive())

    def _reply(self) -> dict[str, Any]:
        def readable() -> bool:
            return bool(select.select([self.proc.stdout], [], [], 0)[0])

        self._wait(readable)
        line = self.proc.stdout.readline()
        self._progress_at = time.monotonic()
        if not line:
            self.proc.wait()
            raise OutputError(f"{self.path}: the writer of {self.what} stopped (exit {self.proc.returncode})")
        reply = json.loads(line)
        if "error" in reply:
            raise OutputError(f"{self.path}: cannot write {self.what}: {reply['error']}")
        return reply

    def finish(self, command: tuple = ("finish",)) -> None:
        """Send `command` (a "finish") and wait until the writer has written and closed the file."""
        self.send(command)
        self._close_input()
        self._reply()  # to "open"
        reply = self._reply()  # to "finish"
        self._wait(lambda: self.proc.poll() is not None)
        self.peak_rss_mb = float(reply.get("peak_rss_mb", float("nan")))
        self.cpu_s = float(reply.get("cpu_s", float("nan")))

    def abort(self) -> None:
        """Tell the writer to drop its file and end (killed when it does not within its stall timeout)."""
        if self.proc.poll() is None:
            self.send(("abort",))
            try:
                self._close_input()
                self._wait(lambda: self.proc.poll() is not None)
            except OutputError:
                pass  # killed: the caller removes the temporary


def start_rerun_writer(path: Path) -> WriterChild:
    """The Rerun recording's child writer (`pipelines.outputs.rerun_recorder`) for `path`, started before
    the recording is opened (`RerunResultWriter(path, ..., writer=...)`).

    This is the one place that says why it starts early: `gslam process` starts it before it imports
    numpy and numba, so that the writer's own start-up (importing rerun and pyarrow) runs on the core
    that the filter's one thread leaves idle until its first update (figures in docs/SPEED.md)."""
    return WriterChild("pipelines.outputs.rerun_recorder", "the Rerun recording", path)


# --- the child writer's side -------------------------------------------------------------------
def usage() -> dict[str, float]:
    """This process's peak resident memory (MB) and processor time (user + system, s) so far.

    The peak is the kernel's high-water mark of this program (`VmHWM`): Linux carries `ru_maxrss` over
    from the process that started this one (the filter's, at the fork), which is not this one's memory."""
    u = resource.getrusage(resource.RUSAGE_SELF)
    peak = u.ru_maxrss / (2**20 if sys.platform == "darwin" else 1024)  # bytes on macOS, KiB on Linux
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                peak = int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        pass
    return {"peak_rss_mb": peak, "cpu_s": u.ru_utime + u.ru_stime}


def _reply(out: BinaryIO, **fields: Any) -> None:
    out.write((json.dumps(fields) + "\n").encode())
    out.flush()


def serve(opener: Callable[..., Any], commands: BinaryIO, replies: BinaryIO) -> int:
    """Carry out the commands read from `commands` on the handler `opener(*open args)` returns: its
    methods named by the commands, `finish`, `abort` and `close` (at the end of the input)."""
    handler = None
    try:
        while True:
            try:
                cmd = pickle.load(commands)
            except EOFError:  # the caller is gone: keep what was received, leave the temporary
                if handler is not None:
                    handler.close()
                return 0
            kind, args = cmd[0], cmd[1:]
            if kind == "open":
                handler = opener(*args)
                _reply(replies, opened=True)
            elif kind == "finish":
                handler.finish(*args)
                _reply(replies, finished=True, **usage())
                return 0
            elif kind == "abort":
                if handler is not None:
                    handler.abort()
                return 0
            else:
                getattr(handler, kind)(*args)
    except Exception as e:  # one line for the caller, which raises it as its own error
        why = e.strerror if isinstance(e, OSError) and e.strerror else f"{type(e).__name__}: {e}"
        _reply(replies, error=why.splitlines()[0])
        return 1


def main(opener: Callable[..., Any]) -> int:
    """The child writer's entry: signals left to the caller, replies on a stdout of their own."""
    # The caller handles Ctrl-C and SIGTERM and then tells this process to finish: ignore them here.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    replies = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # anything printed goes to stderr, not the replies
    return serve(opener, sys.stdin.buffer, replies)
