"""`gslam localise`: find the robot in a saved map."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.common import check_outputs
from pipelines.cli.errors import fail, guarded
from pipelines.cli.progress import reporting


@guarded
def localise(
    map_path: Annotated[
        Path, typer.Argument(metavar="MAP", help="The map: a `gslam process` result .mcap or a map_server .yaml.")
    ],
    input_mcap: Annotated[
        Path,
        typer.Argument(
            metavar="IN",
            help="Input MCAP from `gslam ingest` with odometry and scans, or a log or bag (ingested first into "
            "OUT.input.mcap, as `gslam process` does).",
        ),
    ],
    output: Annotated[Path, typer.Argument(metavar="OUT", help="Result MCAP.")],
    initial_pose: Annotated[
        tuple[float, float, float] | None,
        typer.Option("--initial-pose", metavar="X Y YAW", help="Start here (m, m, rad, map frame); else global."),
    ] = None,
    initial_sigma: Annotated[
        tuple[float, float] | None,
        typer.Option("--initial-sigma", metavar="XY YAW", help="Spread (sd, m and rad) around --initial-pose."),
    ] = None,
    rrd: Annotated[Path | None, typer.Option("--rrd", help="Rerun recording (default: OUT with .rrd).")] = None,
    no_rrd: Annotated[bool, typer.Option("--no-rrd", help="Do not write the Rerun recording.")] = False,
    seed: Annotated[int, typer.Option("--seed", min=0, max=2**32 - 1, help="Seed of the particle filter.")] = 0,
    max_particles: Annotated[
        int, typer.Option("--max-particles", min=1, help="KLD sampling's largest count after the first update.")
    ] = 5000,
    global_particles: Annotated[
        int, typer.Option("--global-particles", min=1, help="Particles of the global search (no initial pose).")
    ] = 20000,
    skip_scans: Annotated[int, typer.Option("--skip-scans", min=0, help="Start at this scan of IN.")] = 0,
) -> None:
    """Localise a log in a saved map: Monte Carlo localisation (KLD-adaptive, scan-matching proposal,
    recovery from kidnapping), with a tracking / lost state and a fitness score at every scan. IN may be a
    raw log or bag, ingested first as `gslam process` does; `gslam eval`, `plot` and `export --tum` read the
    result. Ctrl-C or SIGTERM keeps the scans done: both outputs finished with them, the result marked
    interrupted (exit 130 / 143)."""
    from gslam.localise import LocaliseConfig
    from pipelines.cli.direct_input import ingested_path, needs_ingest, prepare
    from pipelines.localise.maps import map_reads
    from pipelines.localise.run import LocaliseRequest, check_options, localise

    check_options(initial_pose, initial_sigma)  # before any file is read
    rrd_path = None if no_rrd else (rrd or output.with_suffix(".rrd"))
    log_format = needs_ingest(input_mcap, "IN")  # a log or bag rather than an MCAP from gslam ingest
    outputs = {"OUT": output, **({"--rrd": rrd_path} if rrd_path is not None else {})}
    if log_format is not None:
        outputs["the ingested input"] = ingested_path(output)
    # What the run reads, the map's own files included (a YAML's image, the input a result names): no output
    # may be one of them. Checked (and the map's YAML read) before the ingest, which may take a while.
    check_outputs(outputs, {**map_reads(map_path), "IN": input_mcap})
    try:
        cfg = LocaliseConfig(seed=seed, max_particles=max_particles, global_particles=global_particles,
                             min_particles=min(100, max_particles))  # fmt: skip
    except ValueError as e:
        fail(str(e))
    if log_format is not None:
        with reporting("ingest", "messages") as (report, _):
            direct = prepare(input_mcap, output, report, log_format, "IN")
        done = "using the earlier ingest" if direct.reused else "ingested it into"
        typer.echo(f"IN {input_mcap} is a {log_format} log: {done} {direct.mcap} (eval, plot and export read it)")
        input_mcap = direct.mcap
    request = LocaliseRequest(map_path, input_mcap, output, rrd_path, initial_pose, initial_sigma, cfg, skip_scans)
    written = " and ".join(str(p) for p in (output, rrd_path) if p is not None)
    summary = None
    try:
        with reporting("localise", "scans") as (report, _):
            summary = localise(request, report)
        typer.echo(f"map {summary.map_source}")
        typer.echo(summary.describe())
        typer.echo(f"wrote {written}")
    except KeyboardInterrupt as e:
        if summary is not None:  # a signal once the outputs were written
            e.add_note(f"wrote {written}: every scan was processed before the signal")
        raise
