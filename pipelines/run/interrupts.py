"""SIGINT and SIGTERM, from the start of `gslam` to its exit: the running step stops, the outputs are
finished with the steps done and marked interrupted, and the exit code is 128 + the signal's number
(130, 143). Standard library only: installed before anything heavy is imported (`install`).

- Before a command runs (imports, option parsing) a signal ends the process with its exit code and
  one line, never a traceback (`install`, `received`).
- While a command runs (`stop_on_signals`), the first signal raises `Stopped` in the main thread. If
  that exception is swallowed on its way (Python drops exceptions raised inside some callbacks, e.g.
  during an import or a finaliser), the run's loop finds the signal with `check` and raises it there.
- While the outputs are being finished (`deferred`), a signal waits for the finish: it is noted, the
  outputs are completed and the signal is raised after. A second one within `ABORT_WITHIN_S` of the
  first aborts the finish (the outputs' temporaries are removed).
- After `Stopped` has been raised, later signals are noted on stderr and ignored, so the cleanup
  completes and the exit code stays 130 / 143 (SIGKILL still ends the process at once; its temporaries
  are removed by the next run writing the same output, see `mcaplog.tempfiles`).
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

ABORT_WITHIN_S = 2.0
"""A second signal within this many seconds of the first, while the outputs are finished, aborts them."""


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


class _State:
    signum: int | None = None
    """The signal that stopped (or is stopping) the run."""
    raised = False
    """`Stopped` was raised for it (it may still have been swallowed: see `check`)."""
    delivered = False
    """The run has seen it (`stop_on_signals` caught it, or the finish is under way)."""
    deferring = 0
    deferred_at: float | None = None
    held = False
    """`hold` has started the deferral of the `deferred` block that follows."""
    command_done = False
    """The command has returned (`command_finished`): a signal now finds its work complete."""


_state = _State()
_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def received() -> int | None:
    """The signal received so far (None: none)."""
    return _state.signum


def _note(text: str) -> None:
    try:
        sys.stderr.write(text + "\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def _handler(signum: int, frame) -> None:
    st = _state
    if st.deferring:
        now = time.monotonic()
        if st.deferred_at is not None and now - st.deferred_at <= ABORT_WITHIN_S:
            st.deferring = 0  # abort the finish
            st.signum = signum
            st.raised = True
            raise Stopped(signum)
        st.deferred_at = now
        st.signum = st.signum or signum
        name = signal.Signals(signum).name
        _note(f"{name}: finishing the outputs first ({name} again within {ABORT_WITHIN_S:g} s aborts them)")
        return
    if st.raised and st.delivered:
        _note(f"{signal.Signals(signum).name} again: still finishing the outputs (SIGKILL aborts)")
        return
    st.signum = signum
    st.raised = True
    raise Stopped(signum)


def _unraisable(unraisable) -> None:
    """Python prints an exception it cannot raise (one raised in a ctypes callback, e.g. while numba loads
    a kernel, or in a finaliser) as "Exception ignored ..." with its traceback. A `Stopped` lost so is not
    an error: the run's loop raises it again between steps (`check`); say nothing of it."""
    if isinstance(unraisable.exc_value, Stopped):
        return
    _default_unraisable(unraisable)


_default_unraisable = sys.unraisablehook


def install() -> None:
    """Handle SIGINT and SIGTERM from now on (in the main thread only): the command line's first act."""
    if threading.current_thread() is threading.main_thread():
        for s in _SIGNALS:
            signal.signal(s, _handler)
        sys.unraisablehook = _unraisable


def check() -> None:
    """Raise `Stopped` if a signal was received and its exception did not reach the run (called between
    steps: a run still stepping has not seen it)."""
    st = _state
    if st.signum is not None and not st.deferring:
        st.raised = True
        raise Stopped(st.signum)


def acknowledge() -> None:
    """The run has caught the signal's `Stopped` and is finishing: later signals are noted, not raised."""
    if _state.signum is not None:
        _state.delivered = True


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise `Stopped` once; later ones are noted and ignored.
    Outside the main thread (where handlers cannot be set) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, _handler) for s in _SIGNALS}
    try:
        yield
    except KeyboardInterrupt:
        _state.delivered = True
        raise
    finally:
        for s, h in previous.items():
            # Once stopping, later signals are ignored until the process has exited: SIG_IGN, because
            # Python's finalisation puts the default (fatal) action back in place of a Python handler.
            signal.signal(s, signal.SIG_IGN if _state.signum is not None else h)


def hold() -> None:
    """From now on a signal waits, as in `deferred`, whose block (which must follow) ends the hold: called
    as the last statement of a run's loop, so no signal falls between the loop and its finish."""
    st = _state
    if not st.held:
        st.held = True
        st.deferring += 1


@contextmanager
def deferred() -> Iterator[None]:
    """Within the block (the outputs being finished) a signal waits: noted, then raised as `Stopped` once
    the block is done; a second one within `ABORT_WITHIN_S` raises at once."""
    st = _state
    if st.signum is not None:
        st.delivered = True  # the run ends because of it: this is its cleanup
    if st.held:
        st.held = False  # `hold` already counted this block
    else:
        st.deferring += 1
    try:
        yield
    finally:
        st.deferring = max(0, st.deferring - 1)
        st.deferred_at = None
    if st.signum is not None and not st.raised:
        st.raised = st.delivered = True
        raise Stopped(st.signum)


def command_finished() -> None:
    """The command returned normally: a signal from now to exit comes after its outputs were written."""
    _state.command_done = True


def after_command() -> bool:
    """The command had returned when the signal came."""
    return _state.command_done


def reset() -> None:
    """Forget any signal received (tests, and a process that runs several commands)."""
    global _state
    _state = _State()
