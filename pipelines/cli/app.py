"""The `gslam` command line: the typer app and its commands, one module each under `pipelines/cli/`.

Each command module parses its options and calls into the packages below (`pipelines.process`,
`pipelines.localise`, `pipelines.evaluation`, `pipelines.bench`, ...); nothing heavy is imported before a
command runs, so `gslam --help` and a refusal stay quick.
"""

from __future__ import annotations

from typing import Annotated

import typer

from gslam import __version__
from pipelines.cli.bench import bench
from pipelines.cli.config import config_cmd
from pipelines.cli.demo import demo
from pipelines.cli.errors import OneLineErrors
from pipelines.cli.eval import evaluate
from pipelines.cli.export import export
from pipelines.cli.info import info
from pipelines.cli.ingest import ingest
from pipelines.cli.localise import localise
from pipelines.cli.plot import plot
from pipelines.cli.process import process
from pipelines.cli.sweep import sweep

app = typer.Typer(
    name="gslam",
    help="G-SLAM: generative particle-filter SLAM with point maps, for MCAP logs and Rerun.",
    no_args_is_help=True,
    add_completion=True,  # --install-completion / --show-completion for bash, zsh, fish, PowerShell
    context_settings={"help_option_names": ["-h", "--help"]},
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # help text as written: "[filter]" is a word, not markup
    cls=OneLineErrors,
)

COMMANDS = {
    "ingest": ingest,
    "info": info,
    "process": process,
    "config": config_cmd,
    "eval": evaluate,
    "plot": plot,
    "export": export,
    "bench": bench,
    "demo": demo,
    "sweep": sweep,
    "localise": localise,
}
"""The commands, in the order `gslam --help` lists them."""

for _name, _command in COMMANDS.items():
    app.command(_name)(_command)


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


def run() -> None:
    """The `gslam` console script: the typer app between two `startup.freeze_heap`: one before the
    command (the garbage collector's full passes while numba loads the compiled kernels then skip the
    modules imported so far), one on the way out, whatever the exit (the interpreter's teardown then
    skips numba's objects); docs/SPEED.md has what each saves."""
    from pipelines.run.startup import freeze_heap

    freeze_heap()  # the modules imported so far
    try:
        app()
    finally:
        freeze_heap()


if __name__ == "__main__":  # python -m pipelines.cli.app
    run()
