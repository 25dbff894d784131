"""`gslam eval`: the metrics of a result."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.errors import guarded


@guarded
def evaluate(
    result: Annotated[Path, typer.Argument(metavar="RESULT", help="Result MCAP from `gslam process`.")],
    reference: Annotated[
        Path | None,
        typer.Option("--reference", help="Input MCAP of the run.", show_default="the input named in the result"),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Accuracy and speed metrics of a result (GPS error, pole map error, relations, time per update)."""
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
