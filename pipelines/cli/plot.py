"""`gslam plot`: a result drawn to a PNG."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.common import check_outputs
from pipelines.cli.errors import guarded


@guarded
def plot(
    result: Annotated[Path, typer.Argument(metavar="RESULT", help="Result MCAP from `gslam process`.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG file to write.")],
    reference: Annotated[
        Path | None,
        typer.Option("--reference", help="Input MCAP of the run.", show_default="the input named in the result"),
    ] = None,
) -> None:
    """The map's probability with the path, GPS and poles; and the position error against time."""
    from pipelines.errors import InputError
    from pipelines.evaluation.evaluate import read_result, recorded_input
    from pipelines.evaluation.plot import plot_result
    from pipelines.run.recorded_input import recorded_input as checked_input

    inputs = {"RESULT": result, "--reference": reference} if reference else {"RESULT": result}
    if reference is None:
        inputs["INPUT (named in RESULT)"] = recorded_input(result)
    check_outputs({"-o": output}, inputs)
    if reference is None:  # the input the result names, if it is still that file; else no GPS or poles
        try:
            reference = checked_input(result, read_result(result).metadata, "--reference")
        except InputError as e:
            typer.secho(f"note: {e}; plotting without its GPS and poles", fg=typer.colors.YELLOW, err=True)
    typer.echo(f"wrote {plot_result(result, output, reference)}")
