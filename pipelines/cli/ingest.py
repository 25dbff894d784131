"""`gslam ingest`: convert a log or bag to the input MCAP."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.common import Format, check_outputs
from pipelines.cli.errors import guarded
from pipelines.cli.progress import reporting


@guarded
def ingest(
    source: Annotated[
        Path,
        typer.Argument(
            metavar="SOURCE",
            help="A log directory or file (Sydney text/.mat, CARMEN .clf/.log[.gz]), or a ROS bag "
            "(ROS 1 .bag; ROS 2 bag directory, .db3 or .mcap).",
        ),
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="The MCAP file to write.")],
    format: Annotated[
        Format, typer.Option("--format", help="Input format; auto detects it from the names.")
    ] = Format.auto,
    dataset: Annotated[
        str | None, typer.Option(help="Dataset name stored in the metadata (default: from the path).")
    ] = None,
    skip_bad_lines: Annotated[
        bool, typer.Option("--skip-bad-lines", help="Drop malformed lines and report how many.")
    ] = False,
    scan_topic: Annotated[
        str | None, typer.Option("--scan-topic", help="ROS bags: the LaserScan topic (default: the only one).")
    ] = None,
    odom_topic: Annotated[
        str | None,
        typer.Option("--odom-topic", help="ROS bags: the Odometry topic (default: the only one, else /tf)."),
    ] = None,
    base_frame: Annotated[
        str | None,
        typer.Option("--base-frame", help="ROS bags: the robot's base frame (default: from the odometry)."),
    ] = None,
) -> None:
    """Convert a Sydney (text or .mat) or CARMEN log, or a ROS bag, to an MCAP with the gslam input channels."""
    import time

    from ingest import ingest as run_ingest
    from ingest.carmen import relations_path_for

    inputs = {"SOURCE": source}
    if source.is_file():
        inputs["its relations file"] = relations_path_for(source)
    check_outputs({"-o": output}, inputs)
    t0 = time.perf_counter()
    with reporting("ingest", "messages") as (report, _):
        result = run_ingest(
            source,
            output,
            format.value,
            dataset,
            skip_bad_lines,
            report,
            scan_topic=scan_topic,
            odom_topic=odom_topic,
            base_frame=base_frame,
        )
    for w in result.log.warnings:
        typer.secho(f"warning: {w}", fg=typer.colors.YELLOW, err=True)
    counts = ", ".join(f"{k} {v}" for k, v in result.counts.items())
    typer.echo(
        f"wrote {result.output} ({result.log.dataset}, {result.log.source_format}) in "
        f"{time.perf_counter() - t0:.2f} s: {counts}"
    )
