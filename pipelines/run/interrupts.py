"""SIGINT and SIGTERM, from the start of `gslam` to its exit: the running step stops, the outputs are
finished with the steps done and marked interrupted, and the exit code is 128 + the signal's number
(130, 143). Standard library only: installed before anything heavy is imported (`install`).

- Before a command runs (imports, option parsing) a signal ends the process with its exit code and
  one line, never a traceback (`install`, `received`). typer turns a `Stopped` raised outside the
  command's body into a silent exit 130 whatever the signal; the command line puts 128 + its number back
  (`unreported_exit_code`), and a signal while the process exits ends it at once with that code (`exiting`).
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

import os
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
    command_started = False
    """The command's body has begun (`stop_on_signals` entered): a signal from now is reported by it."""
    phase: str | None = None
    """Where `Stopped` was last raised: "before", "during" or "after" the command's body (`_stop`)."""


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


def _stop(signum: int) -> Stopped:
    """The `Stopped` to raise for `signum`, noting where it is raised: before the command's body began,
    during it (the command reports it, with its exit code) or after it returned."""
    st = _state
    st.phase = "after" if st.command_done else "during" if st.command_started else "before"
    return Stopped(signum)


def _handler(signum: int, frame) -> None:
    st = _state
    if st.deferring:
        now = time.monotonic()
        if st.deferred_at is not None and now - st.deferred_at <= ABORT_WITHIN_S:
            st.deferring = 0  # abort the finish
            st.signum = signum
            st.raised = True
            raise _stop(signum)
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
    raise _stop(signum)


def _unraisable(unraisable) -> None:
    """Python prints an exception it cannot raise (one raised in a ctypes callback, e.g. while numba loads
    a kernel, or in a finaliser) as "Exception ignored ..." with its traceback. A `Stopped` lost so is not
    an error: the run's loop raises it again between steps (`check`); say nothing of it."""
    if isinstance(unraisable.exc_value, Stopped):
        return
    _default_unraisable(unraisable)


_default_unraisable = sys.unraisablehook


def behind(e: BaseException) -> KeyboardInterrupt | None:
    """The signal's `KeyboardInterrupt` that `e` stands for, or None. A handler's exception raised inside
    some calls comes out wrapped: Python 3.11 turns one raised in a `__set_name__` (a class body being
    created, e.g. while numba imports) into a RuntimeError whose cause it is. When a signal has come, an
    exception with it in its chain (cause or context) is that signal, not an error."""
    seen: set[int] = set()
    link: BaseException | None = e
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return link
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return None


def as_stop(e: BaseException) -> BaseException:
    """What ended a run's loop: `e`, or the signal's `Stopped` where a signal has come and `e` is some other
    error (raised inside an import or a compiled kernel's call, the handler's exception comes back wrapped,
    e.g. as a RuntimeError or SystemError)."""
    signum = received()
    if not isinstance(e, KeyboardInterrupt) and signum is not None:
        return Stopped(signum)
    return e


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
        raise _stop(st.signum)


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
    _state.command_started = True
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


class WholeStep:
    """Within the block (one step written to every output and counted) a signal waits, and is raised as
    `Stopped` when the block ends: a step is in the outputs whole, and counted, or not at all, so an
    interrupted result holds exactly the steps its message says. A second signal within
    `ABORT_WITHIN_S` raises at once, as in `deferred`. A class rather than a generator: it runs at every
    scan."""

    __slots__ = ()

    def __enter__(self) -> None:
        _state.deferring += 1

    def __exit__(self, kind, value, traceback) -> None:
        st = _state
        st.deferring = max(0, st.deferring - 1)
        if kind is None and st.signum is not None and not st.raised and not st.deferring:
            st.deferred_at = None
            st.raised = True
            raise _stop(st.signum)


whole_step = WholeStep()
"""`with interrupts.whole_step:` around the writing and counting of one step (`gslam process`) or scan
(`gslam localise`)."""


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
        raise _stop(st.signum)


def command_finished() -> None:
    """The command returned normally: a signal from now to exit comes after its outputs were written."""
    _state.command_done = True


def after_command() -> bool:
    """The command had returned when the signal came."""
    return _state.command_done


def signal_phase() -> str | None:
    """Where the signal's `Stopped` was raised: "before" the command's body began (while the command line
    loads or parses its options), "during" it, or "after" it returned; None when no signal came or its
    exception was lost on its way before anything raised it again (`_unraisable`)."""
    return None if _state.signum is None else _state.phase


def unreported_exit_code(code: object) -> int | None:
    """The exit code (128 + the signal's number) for a process about to exit with `code` after a signal
    the command did not report: one raised outside the command's body (before it began or after it
    returned), which typer turns into a silent exit 130 whatever the signal (so a SIGTERM while `gslam`
    loaded ended 130, not 143), or one whose exception was lost and the command ended otherwise. None when
    no signal came, or the command reported it (then `code` is already 128 + its number)."""
    st = _state
    if st.signum is None or (st.phase == "during" and code == 128 + st.signum):
        return None
    return 128 + st.signum


def _exit_now(signum: int, frame) -> None:
    """A signal while the process exits (the command has ended, its outputs written or removed, its exit
    decided): nothing is left to finish, so it ends the process at once, with 128 + its number."""
    _note(f"interrupted ({signal.Signals(signum).name}) while gslam exited (the command had ended)")
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    os._exit(128 + signum)


def end_now(code: int) -> None:
    """End a process that a signal stopped, once its command has finished or removed its outputs and said
    so: flush the standard streams and exit with `code` without the interpreter's teardown. A signal can
    land inside an import or a compile (numba's LLVM, a C extension half initialised); tearing such a
    process down has crashed it (a segmentation fault after the one-line message, about one run in a few
    dozen), turning exit 130 into -11. Nothing is left to do at that point: the writers have finished or
    dropped their files and the child writers have ended."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    os._exit(code)


def exiting() -> None:
    """The command line is on its way out (its exit code is decided): a first signal from now ends the
    process at once with 128 + its number (`_exit_now`) instead of raising into the interpreter's teardown,
    where it would print "Exception ignored" or a traceback; after an earlier signal, later ones are
    ignored (the exit code stays the first one's)."""
    if threading.current_thread() is threading.main_thread():
        for s in _SIGNALS:
            signal.signal(s, _exit_now if _state.signum is None else signal.SIG_IGN)


def reset() -> None:
    """Forget any signal received (tests, and a process that runs several commands)."""
    global _state
    _state = _State()
