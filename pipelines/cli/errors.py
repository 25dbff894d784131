"""How the command line fails: one line on stderr and a non-zero exit, never a traceback.

- usage errors (an option's type, range or choice, a missing argument): `OneLineErrors`, exit 2;
- bad input or options found while running: `guarded`, exit 2;
- SIGINT / SIGTERM: outputs finished and marked interrupted by the command, exit 130 / 143;
- anything else is an internal error (exit 1), with the traceback under GSLAM_DEBUG=1.
"""

from __future__ import annotations

import functools
import os
import signal
import sys

import typer
from typer.core import TyperGroup

from mcaplog.tempfiles import final_name
from pipelines.errors import InputError, OptionError, OutputError
from pipelines.run import interrupts
from pipelines.run.interrupts import exit_code_of, stop_on_signals


def fail(message: str, code: int = 2) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code)


# typer may carry its own copy of click: take the exception classes from the ones typer raises.
_ClickException = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")
_NO_ARGS_IS_HELP = getattr(sys.modules[_ClickException.__module__], "NoArgsIsHelpError", ())


class OneLineErrors(TyperGroup):
    """A command group whose usage errors are one line: `error: <what> (see: gslam CMD --help)`."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        try:
            code = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except _NO_ARGS_IS_HELP as e:
            e.show()
            sys.exit(e.exit_code)
        except _ClickException as e:
            where = getattr(getattr(e, "ctx", None), "command_path", None) or "gslam"
            typer.secho(f"error: {e.format_message()} (see: {where} --help)", fg=typer.colors.RED, err=True)
            sys.exit(e.exit_code)
        except typer.Abort:  # click's name for a KeyboardInterrupt outside a command (while parsing)
            signum = interrupts.received()
            if signum is not None:
                after = (
                    " after the command had finished (its outputs are written)" if interrupts.after_command() else ""
                )
                typer.secho(f"interrupted ({signal.Signals(signum).name}){after}", fg=typer.colors.YELLOW, err=True)
                sys.exit(128 + signum)
            typer.secho("error: aborted", fg=typer.colors.RED, err=True)
            sys.exit(1)
        sys.exit(code if isinstance(code, int) else 0)


def _os_error_line(e: OSError) -> str:
    """`path: reason` for the user's path (a temporary's name is mapped to the output it stands for)."""
    where = final_name(str(e.filename)) if e.filename else ""
    why = e.strerror or str(e)
    return f"{where}: {why}" if where else why


def _signals_unwrapped(fn, *args, **kwargs):
    """`fn(...)`, with a signal's exception that came out wrapped in another (`interrupts.behind`, e.g. a
    RuntimeError from an import the signal landed in) raised as itself: it is reported as the signal,
    not as an internal error."""
    try:
        return fn(*args, **kwargs)
    except Exception as e:
        stop = interrupts.behind(e)
        if stop is None:
            raise
        raise stop from None


def _report_interrupt(e: KeyboardInterrupt) -> None:
    """One line for a SIGINT / SIGTERM that stopped the command, and its exit code (130 / 143)."""
    what = "; ".join([f"interrupted ({e.args[0] if e.args else 'SIGINT'})", *getattr(e, "__notes__", [])])
    typer.secho(what, fg=typer.colors.YELLOW, err=True)
    raise typer.Exit(exit_code_of(e)) from None


def guarded(fn):
    """Run a command with SIGINT/SIGTERM handled, turning known bad-input errors into one clear line."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from ingest.textlog import IngestError

        with stop_on_signals():
            try:
                done = _signals_unwrapped(fn, *args, **kwargs)
                interrupts.command_finished()
                return done
            except typer.Exit:
                raise
            except (IngestError, InputError, OptionError, OutputError) as e:
                fail(str(e))
            except BrokenPipeError:  # output piped into e.g. `head`
                sys.stderr.close()
                raise typer.Exit(0) from None
            except KeyboardInterrupt as e:
                _report_interrupt(e)
            except OSError as e:  # missing, unreadable or unwritable files, disk full, ...
                if os.environ.get("GSLAM_DEBUG"):
                    raise
                fail(_os_error_line(e))
            except ValueError as e:
                if os.environ.get("GSLAM_DEBUG"):
                    raise
                fail(str(e))
            except Exception as e:  # an internal error: one line unless GSLAM_DEBUG asks for the traceback
                if os.environ.get("GSLAM_DEBUG"):
                    raise
                fail(f"internal error: {type(e).__name__}: {e} (set GSLAM_DEBUG=1 for the traceback)", code=1)

    return wrapper
