"""The `gslam` command line: a thin typer layer that builds configs and calls into the packages."""

from __future__ import annotations

import functools
import json
import os
import sys
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from gslam import __version__

app = typer.Typer(
    name="gslam",
    help="G-SLAM: generative particle-filter SLAM with point maps, for MCAP logs and Rerun.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"gslam {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """G-SLAM: generative particle-filter SLAM with point maps, for MCAP logs and Rerun."""


def fail(message: str, code: int = 2) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code)


def guarded(fn):
    """Turn known bad-input errors into one clear line and a non-zero exit (no traceback)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from ingest.textlog import IngestError
        from pipelines.errors import InputError

        try:
            return fn(*args, **kwargs)
        except typer.Exit:
            raise
        except (IngestError, InputError, FileNotFoundError, IsADirectoryError, PermissionError) as e:
            fail(str(e))
        except ValueError as e:
            if os.environ.get("GSLAM_DEBUG"):
                raise
            fail(str(e))
        except BrokenPipeError:  # output piped into e.g. `head`
            sys.stderr.close()
            raise typer.Exit(0) from None
        except KeyboardInterrupt:
            typer.secho("interrupted", fg=typer.colors.YELLOW, err=True)
            raise typer.Exit(130) from None
        except Exception as e:  # an internal error: one line unless GSLAM_DEBUG asks for the traceback
            if os.environ.get("GSLAM_DEBUG"):
                raise
            fail(f"internal error: {type(e).__name__}: {e} (set GSLAM_DEBUG=1 for the traceback)", code=1)

    return wrapper


def invocation(ctx: typer.Context) -> str:
    """The command line as typed (from sys.argv under the real `gslam` script), else rebuilt from the
    parsed parameters of the current command (e.g. under a test runner)."""
    import shlex

    if Path(sys.argv[0]).name == "gslam":
        return shlex.join(["gslam", *sys.argv[1:]])
    parts = [ctx.command_path]
    for param in ctx.command.params:
        value = ctx.params.get(param.name)
        if value in (None, False) or value == [] or (param.default is not None and value == param.default):
            continue
        if param.param_type_name == "argument":
            parts.append(shlex.quote(str(value)))
            continue
        flag = max(param.opts, key=len)
        values = value if isinstance(value, list | tuple) else [value]
        for v in values:
            parts.append(flag if v is True else f"{flag} {shlex.quote(str(getattr(v, 'value', v)))}")
    return " ".join(parts)


def scan_progress(bar):
    """A `progress(done, total, step_ms)` callback for the filter that shows scans per second on `bar`."""
    task = bar.add_task("G-SLAM", total=None, rate="")

    def progress(done: int, total: int, step_ms: float) -> None:
        if done % 5 == 0 or done == total:
            elapsed = bar.tasks[task].elapsed or 1e-9
            bar.update(task, completed=done, total=total, rate=f"{done / elapsed:.0f} scans/s")

    return progress


def progress_bar():
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        transient=False,
        disable=not sys.stderr.isatty() and not os.environ.get("GSLAM_PROGRESS"),
        console=None,
    )


class Format(StrEnum):
    auto = "auto"
    sydney_text = "sydney-text"
    sydney_mat = "sydney-mat"
    carmen = "carmen"
    rosbag = "rosbag"


@app.command()
@guarded
def ingest(
    source: Annotated[
        Path,
        typer.Argument(
            help="A log directory or file (Sydney text/.mat, CARMEN .clf/.log[.gz]), or a ROS bag "
            "(ROS 1 .bag; ROS 2 bag directory, .db3 or .mcap)."
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

    t0 = time.perf_counter()
    with progress_bar() as bar:
        task = bar.add_task("ingest", total=None, rate="")

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        report = run_ingest(
            source,
            output,
            format.value,
            dataset,
            skip_bad_lines,
            progress,
            scan_topic=scan_topic,
            odom_topic=odom_topic,
            base_frame=base_frame,
        )
    for w in report.log.warnings:
        typer.secho(f"warning: {w}", fg=typer.colors.YELLOW, err=True)
    counts = ", ".join(f"{k} {v}" for k, v in report.counts.items())
    typer.echo(
        f"wrote {report.output} ({report.log.dataset}, {report.log.source_format}) in "
        f"{time.perf_counter() - t0:.2f} s: {counts}"
    )


@app.command()
@guarded
def info(
    file: Annotated[Path, typer.Argument(help="An MCAP file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Channels, message counts, schemas, start, end and duration of an MCAP file."""
    from pipelines.inspect import mcap_info

    data = mcap_info(file)
    if as_json:
        typer.echo(json.dumps(data, indent=2))
        return
    typer.echo(f"{file}")
    typer.echo(f"  start {data['start_s']:.3f} s, end {data['end_s']:.3f} s, duration {data['duration_s']:.3f} s")
    width = max((len(t) for t in data["channels"]), default=10)
    for topic, count in data["channels"].items():
        typer.echo(f"  {topic:<{width}}  {count:>7}  {data['schemas'][topic]}")
    for name, record in data["metadata"].items():
        typer.echo(f"  metadata {name}: {json.dumps(record)[:200]}")


def run() -> None:  # pragma: no cover
    app()


def _load_config_file(path: Path | None) -> dict:
    if path is None:
        return {}
    import tomllib

    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: config file not found") from None
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{path}: not valid TOML ({e})") from None


@app.command()
@guarded
def process(
    ctx: typer.Context,
    input: Annotated[Path, typer.Argument(help="Input MCAP from `gslam ingest`.")],
    output: Annotated[Path, typer.Argument(help="Result MCAP to write.")],
    rrd: Annotated[
        Path | None, typer.Option("--rrd", help="Rerun recording to write (default: OUTPUT with .rrd).")
    ] = None,
    no_rrd: Annotated[bool, typer.Option("--no-rrd", help="Do not write a Rerun recording.")] = False,
    particles: Annotated[int | None, typer.Option("--particles", "-N", help="Number of particles N.")] = None,
    points: Annotated[int | None, typer.Option("--points", "-M", help="New points per observation M.")] = None,
    seed: Annotated[int | None, typer.Option("--seed", help="Random seed.")] = None,
    vehicle: Annotated[str | None, typer.Option("--vehicle", help="Vehicle preset: carpark or paper.")] = None,
    config: Annotated[
        Path | None, typer.Option("--config", help="TOML file: [filter] options and run options.")
    ] = None,
    set_: Annotated[
        list[str] | None, typer.Option("--set", help="Filter option override, NAME=VALUE (repeatable).")
    ] = None,
    max_scans: Annotated[int | None, typer.Option("--max-scans", help="Stop after this many scans.")] = None,
    method: Annotated[
        str | None,
        typer.Option("--method", help="gslam (default), or a baseline: fastslam1, fastslam2, grid, grid-hr."),
    ] = None,
    grid_cells: Annotated[
        int | None, typer.Option("--grid-cells", help="Cells of the grid baselines (default 3000 / 48000).")
    ] = None,
    threads: Annotated[
        int | None,
        typer.Option("--threads", min=1, help="Threads of the filter's particle loops (default: all cores)."),
    ] = None,
    occupancy: Annotated[
        bool, typer.Option("--occupancy", help="Also write the final occupancy grid on /map/occupancy.")
    ] = False,
) -> None:
    """Run G-SLAM (or a baseline) over an input MCAP; write the result MCAP and a Rerun recording."""
    from gslam.config import FilterConfig
    from pipelines.process import process as run_process
    from pipelines.runner import RunConfig

    data = _load_config_file(config)
    filter_opts = dict(data.pop("filter", {}))
    for item in set_ or []:
        if "=" not in item:
            raise ValueError(f"--set expects NAME=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        try:
            filter_opts[k.strip()] = json.loads(v)
        except json.JSONDecodeError:
            filter_opts[k.strip()] = v
    for k, v in (("particles", particles), ("points_per_observation", points), ("seed", seed)):
        if v is not None:
            filter_opts[k] = v
    run_opts = {k: v for k, v in data.items() if k in RunConfig.RUN_OPTIONS}
    unknown = sorted(set(data) - set(run_opts))
    if unknown:
        raise ValueError(f"{config}: unknown option(s) {', '.join(unknown)}")
    if vehicle is not None:
        run_opts["vehicle"] = vehicle
    if max_scans is not None:
        run_opts["max_scans"] = max_scans
    if method is not None:
        run_opts["method"] = method
    if grid_cells is not None:
        run_opts["grid_cells"] = grid_cells
    if threads is not None:
        run_opts["threads"] = threads
    if occupancy:
        run_opts["occupancy"] = True
    cfg = RunConfig(filter=FilterConfig.from_dict(filter_opts), **run_opts)
    from pipelines.runner import METHODS

    if cfg.method not in METHODS:
        raise ValueError(f"unknown method {cfg.method!r}; choose one of {', '.join(METHODS)}")
    if cfg.vehicle is not None:
        from gslam.vehicle import vehicle_preset

        vehicle_preset(cfg.vehicle)
    rrd_path = None if no_rrd else (rrd or output.with_suffix(".rrd"))
    with progress_bar() as bar:
        progress = scan_progress(bar)

        summary = run_process(input, output, rrd_path, cfg, progress, command=invocation(ctx))
    typer.echo(
        f"{summary.steps} steps of {summary.scans_in_log} scans; final map {summary.final_map_points} points; "
        f"{summary.ms_per_step_filter_median:.1f} ms per step (filter), "
        f"{summary.ms_per_step_median:.1f} ms end to end; "
        f"real-time factor {summary.real_time_factor:.1f}"
    )
    typer.echo(f"wrote {summary.output}")
    if summary.rrd is not None:
        typer.echo(f"wrote {summary.rrd}  (open it with: rerun {summary.rrd})")


@app.command("eval")
@guarded
def evaluate(
    result: Annotated[Path, typer.Argument(help="Result MCAP from `gslam process`.")],
    reference: Annotated[
        Path | None, typer.Option("--reference", help="Input MCAP (default: from the result's metadata).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Accuracy and speed metrics of a result (GPS error, pole map error, relations, time per step)."""
    from pipelines.evaluate import evaluate_result

    metrics = evaluate_result(result, reference)
    if as_json:
        typer.echo(json.dumps(metrics, indent=2))
        return
    for k, v in metrics.items():
        shown = "n/a" if v is None else (f"{v:.4g}" if isinstance(v, float) else str(v))
        typer.echo(f"{k:<28} {shown}")


@app.command()
@guarded
def plot(
    result: Annotated[Path, typer.Argument(help="Result MCAP from `gslam process`.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG file to write.")],
    reference: Annotated[
        Path | None, typer.Option("--reference", help="Input MCAP (default: from the metadata).")
    ] = None,
) -> None:
    """The map's probability with the path, GPS and poles; and the position error against time."""
    from pipelines.plot import plot_result

    typer.echo(f"wrote {plot_result(result, output, reference)}")


@app.command()
@guarded
def export(
    result: Annotated[Path, typer.Argument(help="Result MCAP from `gslam process`.")],
    tum: Annotated[Path | None, typer.Option("--tum", help="Write the final best trajectory (TUM format).")] = None,
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
    resolution: Annotated[float, typer.Option("--resolution", help="Occupancy cell size [m].")] = 0.05,
) -> None:
    """Export a result for other tools: trajectory as TUM (evo reads it), map as CSV, occupancy grid as a
    map_server map (PGM + YAML, for ROS navigation)."""
    from pipelines.export import export_result

    if tum is None and map_csv is None and occupancy is None:
        raise ValueError("nothing to export: give --tum, --map and/or --occupancy")
    if not resolution > 0:
        raise ValueError(f"--resolution must be positive, got {resolution}")
    for path in export_result(result, tum, map_csv, occupancy, input, resolution):
        typer.echo(f"wrote {path}")


@app.command()
@guarded
def bench(
    ctx: typer.Context,
    quick: Annotated[bool, typer.Option("--quick", help="A small subset (N 2 M 4, N 8 M 10; one seed).")] = False,
    methods: Annotated[
        str,
        typer.Option(
            "--methods", help="Comma-separated: gslam, fastslam1, fastslam2, grid, grid-hr, or all (adds Table 4)."
        ),
    ] = "gslam",
    seeds: Annotated[int | None, typer.Option("--seeds", help="Seeds per cell (default 3; 1 with --quick).")] = None,
    data: Annotated[Path, typer.Option("--data", help="Car Park log directory (or an ingested MCAP).")] = Path(
        "../shared/datasets/carpark"
    ),
    output: Annotated[
        Path | None,
        typer.Option(
            "-o", "--output", help="Markdown file (e.g. docs/BENCHMARKS.md): the suite's section is rewritten."
        ),
    ] = None,
    suite: Annotated[
        str,
        typer.Option(
            "--suite",
            help="carpark: the paper's Tables 3 and 4; freiburg: relations error on the Freiburg indoor logs "
            "(N 30, seeds 0..SEEDS-1); speed: whole-run wall time, ms per update and peak memory (median of 3).",
        ),
    ] = "carpark",
    freiburg: Annotated[
        Path, typer.Option("--freiburg", help="Directory with the Freiburg CARMEN logs (freiburg and speed suites).")
    ] = Path("../shared/datasets/freiburg"),
    threads: Annotated[str, typer.Option("--threads", help="speed suite: comma-separated thread counts.")] = "1,2",
) -> None:
    """Benchmarks into docs/BENCHMARKS.md: the paper's Tables 3 and 4 on the Car Park log (beside the paper's
    figures), the Freiburg indoor logs (beside GMapping), and speed."""
    import tempfile
    import time

    from pipelines.bench import FULL_GRID, METHODS, QUICK_GRID, machine_description, markdown_table, run_bench, versions
    from pipelines.bench_suites import freiburg_section, replace_section, run_suite, speed_section

    if suite not in ("carpark", "freiburg", "speed"):
        raise ValueError(f"--suite must be carpark, freiburg or speed, got {suite!r}")
    command = invocation(ctx)
    t0 = time.perf_counter()
    if suite != "carpark":
        logs = [freiburg / "mit-csail.clf.gz", freiburg / "intel.clf.gz"]
        for log in logs:
            if not log.exists():
                raise FileNotFoundError(f"{log}: Freiburg log not found (--freiburg DIR)")
        echo = lambda s: typer.echo(s, err=True)  # noqa: E731
        if suite == "freiburg":
            n_seeds = seeds if seeds is not None else 5
            runs = run_suite("freiburg", logs, [30], list(range(n_seeds)), [0], 1, echo)
            text = freiburg_section(runs, command, machine_description(), versions())
        else:
            if not data.is_dir() and not data.exists():
                raise FileNotFoundError(f"{data}: Car Park log not found (--data)")
            counts = [int(k) for k in threads.split(",") if k.strip()]
            runs = []
            for log, ns in ((data, [8, 30]), (logs[0], [30]), (logs[1], [30])):
                runs += run_suite("speed", [log], ns, [0], counts, 3, echo)
            text = speed_section(runs, command, machine_description(), versions(), 3)
    else:
        chosen = [m.strip() for m in methods.split(",") if m.strip()]
        if chosen == ["all"]:
            chosen = list(METHODS)
        missing = [m for m in chosen if m not in METHODS]
        if missing:
            raise ValueError(f"method(s) {', '.join(missing)} not available yet; available: {', '.join(METHODS)}")
        n_seeds = seeds if seeds is not None else (1 if quick else 3)
        if n_seeds < 1:
            raise ValueError("--seeds must be at least 1")
        grid = QUICK_GRID if quick else FULL_GRID
        with tempfile.TemporaryDirectory(prefix="gslam-bench-in-") as tmp:
            if data.is_dir():
                from ingest import ingest as run_ingest

                input_mcap = Path(tmp) / "carpark.mcap"
                run_ingest(data, input_mcap)
            else:
                input_mcap = data
            results = run_bench(
                input_mcap, grid, n_seeds, progress=lambda s: typer.echo(s, err=True), methods=tuple(chosen)
            )
        text = markdown_table(results, n_seeds, command, time.perf_counter() - t0)
    if output is not None:
        from pipelines.export import _atomic_write

        _atomic_write(output, replace_section(output, suite, text))
        typer.echo(f"wrote {output}")
    else:
        typer.echo(text)


@app.command()
@guarded
def demo(
    out: Annotated[Path, typer.Option("--out", help="Directory for the simulated log and the results.")] = Path(
        "recordings/demo"
    ),
    seed: Annotated[int, typer.Option("--seed", help="Seed of the simulation and the filter.")] = 0,
    particles: Annotated[int, typer.Option("--particles", "-N", help="Number of particles N.")] = 8,
    points: Annotated[int, typer.Option("--points", "-M", help="New points per observation M.")] = 10,
) -> None:
    """Simulate a Car Park-like log, then ingest, process, evaluate against the truth and plot it."""
    from pipelines.demo import run_demo

    with progress_bar() as bar:
        progress = scan_progress(bar)

        run_demo(
            out,
            seed,
            particles,
            points,
            say=bar.console.print if bar.console.is_terminal else typer.echo,
            progress=progress,
        )


@app.command()
@guarded
def sweep(
    spec: Annotated[
        Path, typer.Argument(help="Sweep spec (TOML): inputs, methods, particles, points, seeds, [options].")
    ],
    workers: Annotated[int, typer.Option("--workers", help="Local worker processes.")] = 2,
    scheduler: Annotated[
        str | None,
        typer.Option("--scheduler", envvar="DASK_SCHEDULER_ADDRESS", help="Dask scheduler, tcp://host:8786."),
    ] = None,
    output: Annotated[Path, typer.Option("-o", "--output", help="Results directory.")] = Path("recordings/sweep"),
    resume: Annotated[bool, typer.Option("--resume", help="Skip tasks whose results exist and are complete.")] = False,
) -> None:
    """Run process + eval over a grid of logs and parameters, locally or on a Dask cluster."""
    from pipelines.sweep import SweepSpec, run_sweep

    if workers < 1:
        raise ValueError("--workers must be at least 1")
    sweep_spec = SweepSpec.load(spec)
    with progress_bar() as bar:
        task = bar.add_task("sweep", total=None, rate="")

        def progress(done: int, total: int, record: dict) -> None:
            failed = f" (last failed: {record['task']['id']})" if record.get("status") == "failed" else ""
            bar.update(task, completed=done, total=total, rate=failed)

        report = run_sweep(sweep_spec, output, workers, scheduler, resume, progress)
    where = scheduler or f"{workers} local workers"
    typer.echo(
        f"{len(report.records)} tasks ({report.skipped} already done, {report.failed} failed) in "
        f"{report.wall_s:.1f} s on {where}"
    )
    typer.echo(f"wrote {report.md_path} and {report.csv_path}")
    if report.failed:
        fail(f"{report.failed} of {len(report.records)} tasks failed (their errors: {report.md_path})", code=1)


if __name__ == "__main__":  # python -m pipelines.cli
    app()
