"""`gslam config`: the options of `gslam process`, as TOML."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.common import check_outputs
from pipelines.cli.errors import fail, guarded


@guarded
def config_cmd(
    dump: Annotated[
        bool, typer.Option("--dump", help="Print every option with its default and one line of help, as TOML.")
    ] = False,
    output: Annotated[
        Path | None,
        typer.Option(
            "-o",
            "--output",
            help="Write the TOML here instead: a new file, or one that `gslam config --dump` wrote earlier (it "
            "is replaced); any other existing file is left alone and refused.",
        ),
    ] = None,
) -> None:
    """The options of `gslam process`: `--dump` gives them all, as a TOML file that `--config` reads back."""
    from mcaplog.tempfiles import write_atomic
    from pipelines.run.config_template import config_toml, is_template

    if not dump:
        fail("give --dump (every option of gslam process with its default, as TOML for --config)")
    text = config_toml()
    if output is None:
        typer.echo(text, nl=False)
        return
    check_outputs({"-o": output}, {})  # a directory, a device, a FIFO: refused
    if os.path.lexists(output) and not is_template(output):  # a result, a log, someone's notes: kept
        fail(
            f"-o {output} exists and is not a config file that `gslam config --dump` wrote: it is never "
            "replaced; give a new path (or remove that file first)"
        )
    write_atomic(output, text)
    typer.echo(f"wrote {output}  (use it with: gslam process IN OUT --config {output})")
