"""`gslam export`: a result for other tools (evo, map_server)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.common import check_outputs
from pipelines.cli.errors import fail, guarded
from pipelines.cli.progress import Report, reporting


@contextmanager
def _phase(what: str, unit: str) -> Iterator[Report]:
    """One slow part of the export, shown as the other commands show their progress."""
    with reporting(f"export: {what}", unit) as (report, _):
        yield report


@guarded
def export(
    result: Annotated[
        Path, typer.Argument(metavar="RESULT", help="Result MCAP from `gslam process` or `gslam localise`.")
    ],
    tum: Annotated[
        Path | None,
        typer.Option(
            "--tum",
            help="Write the trajectory (TUM format): the final best one of a process result, the estimate at "
            "every scan of a localisation result.",
        ),
    ] = None,
    reference: Annotated[
        Path | None,
        typer.Option(
            "--reference",
            help="Write the input's GPS (or true trajectory) as TUM at the scan stamps of --tum, for evo.",
        ),
    ] = None,
    map_csv: Annotated[
        Path | None, typer.Option("--map", help="Write the final map as CSV (x, y, probability).")
    ] = None,
    occupancy: Annotated[
        Path | None,
        typer.Option("--occupancy", help="Write a map_server map: this YAML and the PGM beside it."),
    ] = None,
    input: Annotated[
        Path | None, typer.Option("--input", help="The input MCAP (default: the path in the result).")
    ] = None,
    resolution: Annotated[
        float | None,
        typer.Option(
            "--resolution",
            help="Occupancy cell size [m]. The result's own grid (process --occupancy) is used when it has "
            "this size; another size is built from the input's scans.",
            show_default="the result's grid, else 0.05",
        ),
    ] = None,
) -> None:
    """Export a result for other tools: trajectory and reference as TUM (evo reads them), map as CSV,
    occupancy grid as a map_server map (PGM + YAML, for ROS navigation). A localisation result exports its
    trajectory and reference (its map is the one it was given)."""
    from pipelines.outputs.export import export_result

    if tum is None and map_csv is None and occupancy is None and reference is None:
        fail("nothing to export: give --tum, --reference, --map and/or --occupancy")
    if resolution is not None and not 0 < resolution <= 10:
        fail(f"--resolution must be in (0, 10] m, got {resolution}")
    from pipelines.evaluation.evaluate import recorded_input

    pgm = occupancy.with_suffix(".pgm") if occupancy is not None else None
    check_outputs(
        {
            "--tum": tum,
            "--reference": reference,
            "--map": map_csv,
            "--occupancy": occupancy,
            "the PGM beside --occupancy": pgm,
        },
        {"RESULT": result, "--input": input, "INPUT (named in RESULT)": recorded_input(result)},
    )
    for path in export_result(result, tum, map_csv, occupancy, input, resolution, reference, _phase):
        typer.echo(f"wrote {path}")
