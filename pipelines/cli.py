"""The `gslam` command line: a thin typer layer that builds configs and calls into the packages."""

from __future__ import annotations

import functools
import json
import os
import sys
from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from gslam import __version__

app = typer.Typer(
    name="gslam",
    help="G-SLAM: generative particle-filter SLAM with point maps, for MCAP logs and Rerun.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"gslam {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """G-SLAM: generative particle-filter SLAM with point maps, for MCAP logs and Rerun."""


def fail(message: str, code: int = 2) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code)


def guarded(fn):
    """Turn known bad-input errors into one clear line and a non-zero exit (no traceback)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from ingest.textlog import IngestError
        from pipelines.errors import InputError

        try:
            return fn(*args, **kwargs)
        except (IngestError, InputError, FileNotFoundError, IsADirectoryError, PermissionError) as e:
            fail(str(e))
        except ValueError as e:
            fail(str(e))
        except KeyboardInterrupt:
            typer.secho("interrupted", fg=typer.colors.YELLOW, err=True)
            raise typer.Exit(130) from None
        except Exception as e:  # an internal error: one line unless GSLAM_DEBUG asks for the traceback
            if os.environ.get("GSLAM_DEBUG"):
                raise
            fail(f"internal error: {type(e).__name__}: {e} (set GSLAM_DEBUG=1 for the traceback)", code=1)

    return wrapper


def progress_bar(description: str, unit: str = "msgs"):
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(),
        transient=False, disable=not sys.stderr.isatty() and not os.environ.get("GSLAM_PROGRESS"),
        console=None,
    )


class Format(str, Enum):
    auto = "auto"
    sydney_text = "sydney-text"
    sydney_mat = "sydney-mat"
    carmen = "carmen"


@app.command()
@guarded
def ingest(
    source: Annotated[Path, typer.Argument(help="A log directory or file (Sydney text/.mat, CARMEN .clf/.log[.gz]).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="The MCAP file to write.")],
    format: Annotated[Format, typer.Option("--format", help="Input format; auto detects it from the names.")] = Format.auto,
    dataset: Annotated[str | None, typer.Option(help="Dataset name stored in the metadata (default: from the path).")] = None,
    skip_bad_lines: Annotated[bool, typer.Option("--skip-bad-lines", help="Drop malformed lines and report how many.")] = False,
) -> None:
    """Convert a Sydney (text or .mat) or CARMEN log to an MCAP with the gslam input channels."""
    import time

    from ingest import ingest as run_ingest

    t0 = time.perf_counter()
    with progress_bar("ingest") as bar:
        task = bar.add_task("ingest", total=None, rate="")

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        report = run_ingest(source, output, format.value, dataset, skip_bad_lines, progress)
    for w in report.log.warnings:
        typer.secho(f"warning: {w}", fg=typer.colors.YELLOW, err=True)
    counts = ", ".join(f"{k} {v}" for k, v in report.counts.items())
    typer.echo(f"wrote {report.output} ({report.log.dataset}, {report.log.source_format}) in "
               f"{time.perf_counter() - t0:.2f} s: {counts}")


@app.command()
@guarded
def info(
    file: Annotated[Path, typer.Argument(help="An MCAP file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Channels, message counts, schemas, start, end and duration of an MCAP file."""
    from pipelines.inspect import mcap_info

    data = mcap_info(file)
    if as_json:
        typer.echo(json.dumps(data, indent=2))
        return
    typer.echo(f"{file}")
    typer.echo(f"  start {data['start_s']:.3f} s, end {data['end_s']:.3f} s, duration {data['duration_s']:.3f} s")
    width = max((len(t) for t in data["channels"]), default=10)
    for topic, count in data["channels"].items():
        typer.echo(f"  {topic:<{width}}  {count:>7}  {data['schemas'][topic]}")
    for name, record in data["metadata"].items():
        typer.echo(f"  metadata {name}: {json.dumps(record)[:200]}")


def run() -> None:  # pragma: no cover
    app()
