"""SIGINT and SIGTERM end a command the same way: the running step stops, the outputs are finished
with the steps done and marked interrupted, and the exit code is 128 + the signal's number (130, 143).

A second signal while the outputs are being finished is noted on stderr and otherwise ignored, so
the cleanup completes and the exit code stays 130 / 143 (SIGKILL still ends the process at once; its
temporaries are removed by the next run writing the same output, see `tempfiles`).
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager


class Stopped(KeyboardInterrupt):
    """Raised in the main thread by SIGINT or SIGTERM; a KeyboardInterrupt, so every handler that
    finishes outputs on Ctrl-C finishes them on SIGTERM too."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    def __repr__(self) -> str:
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def exit_code_of(e: KeyboardInterrupt) -> int:
    """130 for Ctrl-C (a plain KeyboardInterrupt), 128 + signal for `Stopped`."""
    return e.exit_code if isinstance(e, Stopped) else 128 + signal.SIGINT


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise `Stopped` once; later ones are noted and ignored.
    Outside the main thread (where handlers cannot be set) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    stopping = False

    def handler(signum: int, frame) -> None:
        nonlocal stopping
        if stopping:
            sys.stderr.write(f"{signal.Signals(signum).name} again: still finishing the outputs (SIGKILL aborts)\n")
            return
        stopping = True
        raise Stopped(signum)

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in previous.items():
            # Once stopping, later signals are ignored until the process has exited: SIG_IGN, because
            # Python's finalisation puts the default (fatal) action back in place of a Python handler.
            signal.signal(s, signal.SIG_IGN if stopping else h)
