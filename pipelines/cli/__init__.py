"""The `gslam` command line (`app`): a thin typer layer over the pipelines, with its one-line errors
(`errors`) and progress reporting (`progress`); signals are `pipelines.run.interrupts`.

`run` is the console script. It handles SIGINT and SIGTERM before it imports anything heavy, so a
Ctrl-C at any moment, even while typer, numpy or numba load, ends with one line and 130 / 143."""

from __future__ import annotations

import signal
import sys


def _before_start(signum: int, frame) -> None:
    """SIGINT / SIGTERM while the command line itself loads (before `run` installs the full handling)."""
    try:
        sys.stderr.write("interrupted before the command started\n")
    except (OSError, ValueError):
        pass
    raise SystemExit(128 + signum)  # no traceback, even inside an import


if sys.argv and sys.argv[0].rsplit("/", 1)[-1] in ("gslam", "-m", "__main__.py"):  # the command, not an import
    for _s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(_s, _before_start)

from typing import Any  # noqa: E402  (after the handlers: a signal while it loads is handled)


def _interrupted(code: int) -> None:
    """Say how a signal the command did not report ended the process (one line), and exit with `code`."""
    from pipelines.run import interrupts

    phase = interrupts.signal_phase()
    name = signal.Signals(code - 128).name if code > 128 else "SIGINT"
    if phase == "before":
        text = "interrupted before the command started"
    elif phase == "after" or (phase is None and interrupts.after_command()):
        text = f"interrupted ({name}) after the command had finished (its outputs are written)"
    else:
        text = f"interrupted ({name})"
    try:
        sys.stderr.write(text + "\n")
    except (OSError, ValueError):
        pass
    interrupts.end_now(code)


def run() -> None:
    """The `gslam` console script. Whatever ends it, a signal gives exit 128 + its number: one the command
    reported, one outside its body (which typer would turn into a silent 130 even for SIGTERM), and one
    while the process exits (`interrupts.exiting`)."""
    from pipelines.run import interrupts

    interrupts.install()
    try:
        from pipelines.cli.app import run as run_app

        run_app()
    except KeyboardInterrupt as e:  # outside a command (a command's own are handled by `errors.guarded`)
        interrupts.exiting()
        _remove_orphans()
        _interrupted(interrupts.exit_code_of(e))
    except Exception as e:  # a signal's exception wrapped on its way (`interrupts.behind`), or a real error
        stop = interrupts.behind(e)
        if stop is None:
            raise
        interrupts.exiting()
        _remove_orphans()
        _interrupted(interrupts.exit_code_of(stop))
    except SystemExit as e:
        interrupts.exiting()
        _remove_orphans()
        code = interrupts.unreported_exit_code(e.code)
        if code is not None:
            _interrupted(code)
        if interrupts.received() is not None and isinstance(e.code, int):
            interrupts.end_now(e.code)  # the command reported the signal; skip the teardown (`end_now`)
        raise
    finally:
        interrupts.exiting()
        _remove_orphans()


def _remove_orphans() -> None:
    """Remove any temporary this process made whose writer never learnt of it (a signal between its
    creation and the writer's hold on it: `mcaplog.tempfiles`). Every output is finished or dropped by now."""
    from mcaplog.tempfiles import remove_own_temporaries

    remove_own_temporaries()


def __getattr__(name: str) -> Any:
    if name == "app":
        from pipelines.cli.app import app

        return app
    raise AttributeError(name)


__all__ = ["app", "run"]
