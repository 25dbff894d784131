"""`gslam plot`: a result drawn to a PNG."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.common import check_outputs
from pipelines.cli.errors import guarded


@guarded
def plot(
    result: Annotated[
        Path, typer.Argument(metavar="RESULT", help="Result MCAP from `gslam process` or `gslam localise`.")
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG file to write.")],
    reference: Annotated[
        Path | None,
        typer.Option(
            "--reference",
            help="A process result: the input MCAP of the run. A localisation result: a `gslam process` result, "
            "a TUM trajectory or an input MCAP to draw and compare with (as `gslam eval --reference`).",
            show_default="the input named in the result",
        ),
    ] = None,
) -> None:
    """A mapping result: the map's probability with the path, GPS and poles; and the position error against
    time. A localisation result: its path over the map, green while tracking and red while lost; the
    fitness and the state against time; and the error against the reference (else the particle count)."""
    from pipelines.errors import InputError
    from pipelines.evaluation.evaluate import read_result, recorded_input
    from pipelines.evaluation.localisation import is_localisation_result
    from pipelines.evaluation.plot import plot_result
    from pipelines.run.recorded_input import recorded_input as checked_input

    inputs = {"RESULT": result, "--reference": reference} if reference else {"RESULT": result}
    if reference is None:
        inputs["INPUT (named in RESULT)"] = recorded_input(result)
    check_outputs({"-o": output}, inputs)
    if is_localisation_result(result):
        from pipelines.evaluation.localisation_plot import plot_localisation

        written, notes = plot_localisation(result, output, reference)
        for note in notes:
            typer.secho(f"note: {note}; plotting without a reference", fg=typer.colors.YELLOW, err=True)
        typer.echo(f"wrote {written}")
        return
    if reference is None:  # the input the result names, if it is still that file; else no GPS or poles
        try:
            reference = checked_input(result, read_result(result).metadata, "--reference")
        except InputError as e:
            typer.secho(f"note: {e}; plotting without its GPS and poles", fg=typer.colors.YELLOW, err=True)
    typer.echo(f"wrote {plot_result(result, output, reference)}")
