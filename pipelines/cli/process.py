"""`gslam process`: run G-SLAM (or a baseline) over an input; write the result MCAP and recording."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.common import DEFAULTS, Method, Vehicle, check_outputs, invocation
from pipelines.cli.errors import fail, guarded
from pipelines.cli.progress import reporting


def _one_output(positional: Path | None, option: Path | None) -> Path:
    """The output given as OUTPUT or as -o (either; both only when they agree)."""
    if positional is not None and option is not None and positional != option:
        fail(f"two outputs: OUTPUT {positional} and -o {option}; give one")
    output = positional or option
    if output is None:
        fail("no output: give the result MCAP to write, as OUTPUT or with -o")
    return output


@guarded
def process(
    ctx: typer.Context,
    input: Annotated[
        Path,
        typer.Argument(
            metavar="INPUT",
            help="Input MCAP from `gslam ingest`, or a log or bag (ingested first into OUTPUT.input.mcap).",
        ),
    ],
    output_arg: Annotated[
        Path | None,
        typer.Argument(metavar="OUTPUT", help="Result MCAP to write (or give it with -o).", show_default=False),
    ] = None,
    output_opt: Annotated[
        Path | None, typer.Option("-o", "--output", help="Result MCAP to write (the same as OUTPUT).")
    ] = None,
    rrd: Annotated[
        Path | None,
        typer.Option("--rrd", help="Rerun recording to write.", show_default="OUTPUT with .rrd"),
    ] = None,
    no_rrd: Annotated[bool, typer.Option("--no-rrd", help="Do not write a Rerun recording.")] = False,
    particles: Annotated[
        int | None,
        typer.Option(
            "--particles", "-N", min=1, max=4096, help="Number of particles N.", show_default=str(DEFAULTS.particles)
        ),
    ] = None,
    points: Annotated[
        int | None,
        typer.Option(
            "--points",
            "-M",
            min=1,
            max=1000,
            help="New points per observation M.",
            show_default=str(DEFAULTS.points_per_observation),
        ),
    ] = None,
    seed: Annotated[
        int | None,
        typer.Option("--seed", min=0, max=2**32 - 1, help="Random seed.", show_default=str(DEFAULTS.seed)),
    ] = None,
    vehicle: Annotated[
        Vehicle | None,
        typer.Option(
            "--vehicle",
            help="Vehicle preset of an Ackermann (Sydney) log.",
            show_default="the one in the input's metadata",
        ),
    ] = None,
    config: Annotated[
        Path | None, typer.Option("--config", help="TOML file: [filter] options and run options.")
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            metavar="NAME=VALUE",
            help="Filter option override, NAME=VALUE (repeatable; docs/CHOICES.md lists them).",
        ),
    ] = None,
    max_scans: Annotated[
        int | None, typer.Option("--max-scans", min=1, help="Stop after this many scans.", show_default="all")
    ] = None,
    method: Annotated[
        Method | None,
        typer.Option("--method", help="G-SLAM, or a baseline.", show_default="gslam"),
    ] = None,
    grid_cells: Annotated[
        int | None,
        typer.Option(
            "--grid-cells",
            min=16,
            max=10_000_000,
            help="Cells of the grid baselines.",
            show_default="3000 for grid, 48000 for grid-hr",
        ),
    ] = None,
    threads: Annotated[
        int | None,
        typer.Option("--threads", min=1, help="Threads of the filter's particle loops (default: all cores)."),
    ] = None,
    occupancy: Annotated[
        bool, typer.Option("--occupancy", help="Also write the final occupancy grid on /map/occupancy.")
    ] = False,
    live: Annotated[
        bool,
        typer.Option(
            "--live",
            help="Stream the recording to a Rerun viewer while the run goes (one is started if none listens; "
            "the web viewer where there is no screen).",
        ),
    ] = False,
    live_url: Annotated[
        str | None,
        typer.Option(
            "--live-url", help="The viewer's gRPC address for --live.", show_default="rerun+http://127.0.0.1:9876/proxy"
        ),
    ] = None,
    continue_from: Annotated[
        Path | None,
        typer.Option(
            "--continue",
            metavar="PREVIOUS",
            help="Go on from this earlier `gslam process` result: find the run in its map, then map on in one "
            "map and one pose graph (the earlier runs' trajectories kept in the result).",
        ),
    ] = None,
    initial_pose: Annotated[
        tuple[float, float, float] | None,
        typer.Option(
            "--initial-pose",
            metavar="X Y YAW",
            help="With --continue: where the first scan stands in PREVIOUS's map (m, m, rad; the base's pose). "
            "Default: found by searching PREVIOUS's whole map with the run's first scans.",
        ),
    ] = None,
    if_lost: Annotated[
        str,
        typer.Option(
            "--if-lost",
            metavar="stop|new",
            help="With --continue, when the run cannot find itself in PREVIOUS's map: stop (an error, nothing "
            "written), or new: map it as a new trajectory in its own frame, PREVIOUS's map and runs kept beside it.",
        ),
    ] = "stop",
    keep_viewer: Annotated[
        bool,
        typer.Option(
            "--keep-viewer",
            help="With --live: leave the Rerun viewer started for it running after the run (by default it is "
            "stopped when the run ends; a viewer that was already running is always left alone).",
        ),
    ] = False,
) -> None:
    """Run G-SLAM (or a baseline) over an input MCAP; write the result MCAP and a Rerun recording."""
    from pipelines.outputs.writer_child import start_rerun_writer

    output = _one_output(output_arg, output_opt)
    if rrd is not None and no_rrd:
        fail(f"--rrd {rrd} and --no-rrd contradict each other: give one")
    if live_url is not None and not live_url.strip():
        fail("--live-url is empty: give the Rerun viewer's address, e.g. rerun+http://127.0.0.1:9876/proxy")
    if initial_pose is not None and continue_from is None:
        fail("--initial-pose goes with --continue (a new map starts at the first scan's odometry pose)")
    if if_lost not in ("stop", "new"):
        fail(f"--if-lost {if_lost}: expected stop or new")
    if if_lost != "stop" and continue_from is None:
        fail("--if-lost goes with --continue")
    rrd_path = None if no_rrd else (rrd or output.with_suffix(".rrd"))
    # Started first, before numpy and numba are imported: see writer_child.start_rerun_writer.
    rrd_writer = None if rrd_path is None else start_rerun_writer(rrd_path)
    summary = None
    viewer = None  # the viewer --live streams to
    failed = False
    try:
        from pipelines.process import process as run_process
        from pipelines.run.options import Setting, parse_set, run_config

        flags = [("particles", particles, "--particles"), ("points_per_observation", points, "--points")]
        flags.append(("seed", seed, "--seed"))
        filter_settings = [parse_set(item) for item in set_ or []]
        filter_settings += [Setting(k, v, f"{flag} {v}") for k, v, flag in flags if v is not None]
        run_flags = [
            ("vehicle", vehicle, "--vehicle"),
            ("max_scans", max_scans, "--max-scans"),
            ("method", method, "--method"),
            ("grid_cells", grid_cells, "--grid-cells"),
            ("threads", threads, "--threads"),
            ("occupancy", True if occupancy else None, "--occupancy"),
        ]
        if live or live_url is not None:
            from pipelines.outputs.rerun_viewer import DEFAULT_LIVE_URL

            run_flags.append(("live_url", live_url or DEFAULT_LIVE_URL, "--live-url"))
        run_settings = [Setting(k, getattr(v, "value", v), f"{flag} {v}") for k, v, flag in run_flags if v is not None]
        cfg = run_config(config, filter_settings, run_settings)
        from pipelines.cli.direct_input import ingested_path, needs_ingest, prepare

        log_format = needs_ingest(input)  # a log or bag rather than an MCAP from gslam ingest
        outputs = {"OUTPUT": output, "--rrd": rrd_path}
        if log_format is not None:
            outputs["the ingested input"] = ingested_path(output)
        check_outputs(outputs, {"INPUT": input, "--config": config, "--continue": continue_from})
        continuation = None
        if continue_from is not None:
            from pipelines.localise.run import check_options
            from pipelines.process import Continuation

            check_options(initial_pose, None)
            continuation = Continuation(continue_from, initial_pose, if_lost)
        if keep_viewer and cfg.live_url is None:
            fail("--keep-viewer goes with --live (or --live-url)")
        if cfg.live_url is not None:
            if rrd_path is None:
                fail("--live streams the Rerun recording: it cannot go with --no-rrd")
            from pipelines.outputs.rerun_viewer import live_viewer

            viewer = live_viewer(cfg.live_url)
            typer.echo(viewer.message)
        if log_format is not None:
            with reporting("ingest", "messages") as (report, _):
                direct = prepare(input, output, report, log_format)
            done = "using the earlier ingest" if direct.reused else "ingested it into"
            typer.echo(f"INPUT {input} is a {log_format} log: {done} {direct.mcap} (eval, plot and export read it)")
            input = direct.mcap
        with reporting("G-SLAM", "scans") as (report, say):
            summary = run_process(
                input, output, rrd_path, cfg, report, command=invocation(ctx), rrd_writer=rrd_writer, notice=say,
                continuation=continuation,
            )  # fmt: skip
        typer.echo(summary.describe())
        typer.echo(f"wrote {summary.output}")
        if summary.rrd is not None:
            from pipelines.outputs.rerun_viewer import open_command

            typer.echo(f"wrote {summary.rrd}  (open it with: {open_command(summary.rrd)})")
    except BaseException as e:
        failed = True
        if rrd_writer is not None:
            rrd_writer.abort()  # nothing to do once the run has finished or aborted it
        if isinstance(e, KeyboardInterrupt) and summary is not None:  # a signal after the run was written
            written = " and ".join(str(p) for p in (summary.output, summary.rrd) if p is not None)
            e.add_note(f"wrote {written}: every scan was processed before the signal")
        raise
    finally:
        if viewer is not None:  # stopped (or left running) however the run ended; one not started here: left alone
            said = viewer.end(keep=keep_viewer)
            if said is not None:
                typer.echo(said, err=failed)
