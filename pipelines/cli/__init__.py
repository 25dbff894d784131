"""The `gslam` command line (`app`): a thin typer layer over the pipelines, with its one-line errors
(`errors`), signals (`signals`) and progress reporting (`progress`)."""

from pipelines.cli.app import app, run

__all__ = ["app", "run"]
