"""`gslam eval`: the metrics of a result (of `gslam process` or of `gslam localise`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.errors import guarded


@guarded
def evaluate(
    result: Annotated[
        Path, typer.Argument(metavar="RESULT", help="Result MCAP from `gslam process` or `gslam localise`.")
    ],
    reference: Annotated[
        Path | None,
        typer.Option(
            "--reference",
            help="A process result: the input MCAP of the run. A localisation result: a `gslam process` result "
            "(its final trajectory, matched by stamp), a TUM trajectory, or an input MCAP (its true poses, GPS or "
            "relations).",
            show_default="the input named in the result",
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Accuracy and speed metrics of a result: for a mapping result the GPS error, pole map error, relations
    and time per update; for a localisation result the share of scans tracked, when a place was first
    claimed, the fitness, the time per scan and the error against a reference where the filter tracks."""
    from pipelines.evaluation.localisation import evaluate_localisation, is_localisation_result

    if is_localisation_result(result):
        metrics = evaluate_localisation(result, reference)
    else:
        from pipelines.evaluation.evaluate import evaluate_result

        metrics = evaluate_result(result, reference)
    if as_json:
        typer.echo(json.dumps(metrics, indent=2))
        return
    for note in metrics["notes"]:
        typer.echo(f"note: {note}")
    for k, v in metrics.items():
        if k == "notes":
            continue
        shown = "n/a" if v is None else (f"{v:.4g}" if isinstance(v, float) else str(v))
        typer.echo(f"{k:<28} {shown}")
