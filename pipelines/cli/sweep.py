"""`gslam sweep`: process and eval over a grid of logs and parameters."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.common import check_outputs
from pipelines.cli.errors import fail, guarded
from pipelines.cli.progress import reporting


@guarded
def sweep(
    spec: Annotated[
        Path,
        typer.Argument(metavar="SPEC", help="Sweep spec (TOML): inputs, methods, particles, points, seeds, [options]."),
    ],
    workers: Annotated[int, typer.Option("--workers", min=1, help="Local worker processes.")] = 2,
    scheduler: Annotated[
        str | None,
        typer.Option("--scheduler", envvar="DASK_SCHEDULER_ADDRESS", help="Dask scheduler, tcp://host:8786."),
    ] = None,
    output: Annotated[Path, typer.Option("-o", "--output", help="Results directory.")] = Path("recordings/sweep"),
    resume: Annotated[bool, typer.Option("--resume", help="Skip tasks whose results exist and are complete.")] = False,
) -> None:
    """Run process + eval over a grid of logs and parameters, locally or on a Dask cluster."""
    from pipelines.bench.sweep import SWEEP_FILES, SweepSpec, run_sweep

    sweep_spec = SweepSpec.load(spec)
    if output.exists() and not output.is_dir():
        fail(f"-o {output} is a file; give a directory for the results")
    inputs = {"SPEC": spec, **{f"input {p}": Path(p) for p in sweep_spec.inputs}}
    check_outputs({f"the sweep's {name}": output / name for name in SWEEP_FILES}, inputs)
    with reporting("sweep", "tasks") as (report, _):
        result = run_sweep(sweep_spec, output, workers, scheduler, resume, report)
    where = scheduler or f"{workers} local workers"
    typer.echo(
        f"{len(result.records)} tasks ({result.skipped} already done, {result.failed} failed) in "
        f"{result.wall_s:.1f} s on {where}"
    )
    typer.echo(f"wrote {result.md_path} and {result.csv_path}")
    if result.failed:
        fail(f"{result.failed} of {len(result.records)} tasks failed (their errors: {result.md_path})", code=1)
