"""`gslam info`: what an MCAP file holds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.errors import guarded


@guarded
def info(
    file: Annotated[Path, typer.Argument(metavar="FILE", help="An MCAP file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Channels, message counts, schemas, start, end and duration of an MCAP file."""
    from mcaplog.tempfiles import describe_temporary
    from pipelines.errors import InputError
    from pipelines.evaluation.mcap_info import mcap_info

    temp = describe_temporary(file)
    if temp is not None and file.exists():
        raise InputError(temp.describe(file))
    data = mcap_info(file)
    if as_json:
        typer.echo(json.dumps(data, indent=2))
        return
    typer.echo(f"{file}")
    typer.echo(f"  start {data['start_s']:.3f} s, end {data['end_s']:.3f} s, duration {data['duration_s']:.3f} s")
    width = max((len(t) for t in data["channels"]), default=10)
    for topic, count in data["channels"].items():
        typer.echo(f"  {topic:<{width}}  {count:>7}  {data['schemas'][topic]}")
    for name, record in data["metadata"].items():  # in full: the sensor's mount, the run's configuration
        typer.echo(f"  metadata {name}:")
        for key, value in record.items() if isinstance(record, dict) else [("", record)]:
            shown = value if isinstance(value, str) else json.dumps(value)
            typer.echo(f"    {key} = {shown}" if key else f"    {shown}")
