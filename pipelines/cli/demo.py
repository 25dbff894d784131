"""`gslam demo`: a simulated log, mapped, evaluated and drawn."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.errors import fail, guarded
from pipelines.cli.progress import reporting


@guarded
def demo(
    out: Annotated[Path, typer.Option("--out", help="Directory for the simulated log and the results.")] = Path(
        "recordings/demo"
    ),
    seed: Annotated[
        int, typer.Option("--seed", min=0, max=2**32 - 1, help="Seed of the simulation and the filter.")
    ] = 0,
    particles: Annotated[
        int,
        typer.Option("--particles", "-N", min=1, max=4096, help="Particles N (the paper's 8, quick)."),
    ] = 8,
    points: Annotated[int, typer.Option("--points", "-M", min=1, max=1000, help="New points per observation M.")] = 10,
) -> None:
    """Simulate a Car Park-like log, then ingest, process, evaluate against the truth and plot it."""
    from pipelines.demo.run import run_demo

    if out.exists() and not out.is_dir():
        fail(f"--out {out} is a file; give a directory")
    with reporting("G-SLAM", "scans") as (report, say):
        run_demo(out, seed, particles, points, say=say, progress=report)
