"""The `gslam` command line: a thin typer layer that builds configs and calls into the packages."""

from __future__ import annotations

import json
import sys
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from gslam import __version__
from gslam.config import FilterConfig
from gslam.vehicle import VEHICLE_PRESETS
from pipelines.cli.errors import OneLineErrors, fail, guarded
from pipelines.cli.progress import reporting
from pipelines.methods import NAMES as METHOD_NAMES

app = typer.Typer(
    name="gslam",
    help="G-SLAM: generative particle-filter SLAM with point maps, for MCAP logs and Rerun.",
    no_args_is_help=True,
    add_completion=True,  # --install-completion / --show-completion for bash, zsh, fish, PowerShell
    context_settings={"help_option_names": ["-h", "--help"]},
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # help text as written: "[filter]" is a word, not markup
    cls=OneLineErrors,
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


def check_outputs(outputs: dict, inputs: dict) -> None:
    from pipelines.outputs.path_checks import check_outputs as check

    check(outputs, inputs)


class Format(StrEnum):
    auto = "auto"
    sydney_text = "sydney-text"
    sydney_mat = "sydney-mat"
    carmen = "carmen"
    rosbag = "rosbag"


Method = StrEnum("Method", [(m.replace("-", "_"), m) for m in METHOD_NAMES])
Vehicle = StrEnum("Vehicle", [(v, v) for v in VEHICLE_PRESETS])
_DEFAULTS = FilterConfig()


@app.command()
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


@app.command()
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


def _one_output(positional: Path | None, option: Path | None) -> Path:
    """The output given as OUTPUT or as -o (either; both only when they agree)."""
    if positional is not None and option is not None and positional != option:
        fail(f"two outputs: OUTPUT {positional} and -o {option}; give one")
    output = positional or option
    if output is None:
        fail("no output: give the result MCAP to write, as OUTPUT or with -o")
    return output


@app.command()
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
            "--particles", "-N", min=1, max=4096, help="Number of particles N.", show_default=str(_DEFAULTS.particles)
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
            show_default=str(_DEFAULTS.points_per_observation),
        ),
    ] = None,
    seed: Annotated[
        int | None,
        typer.Option("--seed", min=0, max=2**32 - 1, help="Random seed.", show_default=str(_DEFAULTS.seed)),
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
) -> None:
    """Run G-SLAM (or a baseline) over an input MCAP; write the result MCAP and a Rerun recording."""
    from pipelines.outputs.writer_process import start_rerun_writer

    output = _one_output(output_arg, output_opt)
    rrd_path = None if no_rrd else (rrd or output.with_suffix(".rrd"))
    # Started first, before numpy and numba are imported: see writer_process.start_rerun_writer.
    rrd_writer = None if rrd_path is None else start_rerun_writer(rrd_path)
    summary = None
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
        if live or live_url:
            from pipelines.outputs.rerun_viewer import DEFAULT_LIVE_URL

            run_flags.append(("live_url", live_url or DEFAULT_LIVE_URL, "--live-url"))
        run_settings = [Setting(k, getattr(v, "value", v), f"{flag} {v}") for k, v, flag in run_flags if v is not None]
        cfg = run_config(config, filter_settings, run_settings)
        from pipelines.cli.direct_input import ingested_path, needs_ingest, prepare

        log_format = needs_ingest(input)  # a log or bag rather than an MCAP from gslam ingest
        outputs = {"OUTPUT": output, "--rrd": rrd_path}
        if log_format is not None:
            outputs["the ingested input"] = ingested_path(output)
        check_outputs(outputs, {"INPUT": input, "--config": config})
        if cfg.live_url is not None:
            if rrd_path is None:
                fail("--live streams the Rerun recording: it cannot go with --no-rrd")
            from pipelines.outputs.rerun_viewer import live_viewer

            typer.echo(live_viewer(cfg.live_url))
        if log_format is not None:
            with reporting("ingest", "messages") as (report, _):
                direct = prepare(input, output, report, log_format)
            done = "using the earlier ingest" if direct.reused else "ingested it into"
            typer.echo(f"INPUT {input} is a {log_format} log: {done} {direct.mcap} (eval, plot and export read it)")
            input = direct.mcap
        with reporting("G-SLAM", "scans") as (report, say):
            summary = run_process(
                input, output, rrd_path, cfg, report, command=invocation(ctx), rrd_writer=rrd_writer, notice=say
            )
        typer.echo(summary.describe())
        typer.echo(f"wrote {summary.output}")
        if summary.rrd is not None:
            from pipelines.outputs.rerun_viewer import open_command

            typer.echo(f"wrote {summary.rrd}  (open it with: {open_command(summary.rrd)})")
    except BaseException as e:
        if rrd_writer is not None:
            rrd_writer.abort()  # nothing to do once the run has finished or aborted it
        if isinstance(e, KeyboardInterrupt) and summary is not None:  # a signal after the run was written
            written = " and ".join(str(p) for p in (summary.output, summary.rrd) if p is not None)
            e.add_note(f"wrote {written}: every scan was processed before the signal")
        raise


@app.command("config")
@guarded
def config_cmd(
    dump: Annotated[
        bool, typer.Option("--dump", help="Print every option with its default and one line of help, as TOML.")
    ] = False,
    output: Annotated[Path | None, typer.Option("-o", "--output", help="Write the TOML here instead.")] = None,
) -> None:
    """The options of `gslam process`: `--dump` gives them all, as a TOML file that `--config` reads back."""
    from mcaplog.tempfiles import write_atomic
    from pipelines.run.config_template import config_toml

    if not dump:
        fail("give --dump (every option of gslam process with its default, as TOML for --config)")
    text = config_toml()
    if output is None:
        typer.echo(text, nl=False)
        return
    check_outputs({"-o": output}, {})
    write_atomic(output, text)
    typer.echo(f"wrote {output}  (use it with: gslam process IN OUT --config {output})")


@app.command("eval")
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


@app.command()
@guarded
def plot(
    result: Annotated[Path, typer.Argument(metavar="RESULT", help="Result MCAP from `gslam process`.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG file to write.")],
    reference: Annotated[
        Path | None,
        typer.Option("--reference", help="Input MCAP of the run.", show_default="the input named in the result"),
    ] = None,
) -> None:
    """The map's probability with the path, GPS and poles; and the position error against time."""
    from pipelines.errors import InputError
    from pipelines.evaluation.evaluate import read_result, recorded_input
    from pipelines.evaluation.plot import plot_result
    from pipelines.run.recorded_input import recorded_input as checked_input

    inputs = {"RESULT": result, "--reference": reference} if reference else {"RESULT": result}
    if reference is None:
        inputs["INPUT (named in RESULT)"] = recorded_input(result)
    check_outputs({"-o": output}, inputs)
    if reference is None:  # the input the result names, if it is still that file; else no GPS or poles
        try:
            reference = checked_input(result, read_result(result).metadata, "--reference")
        except InputError as e:
            typer.secho(f"note: {e}; plotting without its GPS and poles", fg=typer.colors.YELLOW, err=True)
    typer.echo(f"wrote {plot_result(result, output, reference)}")


@app.command()
@guarded
def export(
    result: Annotated[Path, typer.Argument(metavar="RESULT", help="Result MCAP from `gslam process`.")],
    tum: Annotated[Path | None, typer.Option("--tum", help="Write the final best trajectory (TUM format).")] = None,
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
    occupancy grid as a map_server map (PGM + YAML, for ROS navigation)."""
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
    for path in export_result(result, tum, map_csv, occupancy, input, resolution, reference):
        typer.echo(f"wrote {path}")


def _corpus_logs(logs: str | None, datasets: Path) -> list[str] | None:
    """The corpus logs `--logs` names (None: all), checked against the corpus; and `--datasets` checked."""
    from pipelines.bench.corpus import FREIBURG_LOGS, RADISH_LOGS

    only = [name.strip() for name in logs.split(",") if name.strip()] if logs else None
    unknown = sorted(set(only or []) - set(FREIBURG_LOGS + RADISH_LOGS))
    if unknown:
        fail(f"--logs: unknown log(s) {', '.join(unknown)}; the corpus: {', '.join(FREIBURG_LOGS + RADISH_LOGS)}")
    if not datasets.is_dir():
        fail(f"--datasets {datasets}: no such directory")
    return only


@app.command()
@guarded
def bench(
    ctx: typer.Context,
    quick: Annotated[bool, typer.Option("--quick", help="A small subset (N 2 M 4, N 8 M 10; one seed).")] = False,
    methods: Annotated[
        str,
        typer.Option("--methods", help=f"Comma-separated: {', '.join(METHOD_NAMES)}, or all (adds Table 4)."),
    ] = "gslam",
    seeds: Annotated[
        int | None, typer.Option("--seeds", min=1, help="Seeds per cell.", show_default="3; 1 with --quick")
    ] = None,
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
            "(N 30, seeds 0..SEEDS-1); speed: whole-run wall time, ms per update and peak memory (median of 3); "
            "robustness: the corpus (Freiburg, Radish with corrupted odometry) beside GMapping and odometry; "
            "localise: `gslam localise` in maps `gslam process` built (global, wrong start, half map, kidnap).",
        ),
    ] = "carpark",
    freiburg: Annotated[
        Path, typer.Option("--freiburg", help="Directory with the Freiburg CARMEN logs (freiburg and speed suites).")
    ] = Path("../shared/datasets/freiburg"),
    gmapping: Annotated[
        Path,
        typer.Option(
            "--gmapping",
            help="GMapping harness directory (speed and robustness suites): GMapping runs beside gslam; "
            "when it is absent the speed table gives GMapping's reference times instead.",
        ),
    ] = Path("../shared/tools/gmapping"),
    datasets: Annotated[
        Path, typer.Option("--datasets", help="The datasets directory (robustness and localise suites: the corpus).")
    ] = Path("../shared/datasets"),
    logs: Annotated[
        str | None,
        typer.Option(
            "--logs", help="Robustness and localise suites: comma-separated corpus logs to run (default: all)."
        ),
    ] = None,
) -> None:
    """Benchmarks into docs/BENCHMARKS.md: the paper's Tables 3 and 4 on the Car Park log (beside the paper's
    figures), the Freiburg indoor logs (beside GMapping), and speed."""
    import tempfile
    import time

    from pipelines.bench.carpark import (
        FULL_GRID,
        QUICK_GRID,
        machine_description,
        markdown_table,
        run_bench,
        versions,
    )
    from pipelines.bench.suites import freiburg_section, replace_section, run_suite, speed_section

    if suite not in ("carpark", "freiburg", "speed", "robustness", "localise"):
        fail(f"--suite {suite}: expected carpark, freiburg, speed, robustness or localise")
    if output is not None:
        check_outputs({"-o": output}, {"--data": data, "--freiburg": freiburg, "--datasets": datasets})
    command = invocation(ctx)
    t0 = time.perf_counter()
    if suite == "robustness":
        from pipelines.bench.robustness import robustness_section, run_robustness

        only = _corpus_logs(logs, datasets)
        harness = gmapping if (gmapping / "run.sh").exists() else None
        if harness is None:
            typer.echo(f"--gmapping {gmapping}: no run.sh there; GMapping is left out", err=True)
        results = run_robustness(
            datasets, list(range(seeds or 3)), lambda s: typer.echo(s, err=True), harness, only=only
        )
        text = robustness_section(results, command, machine_description(), versions(), 30, 0)
    elif suite == "localise":
        from pipelines.bench.corpus import FREIBURG_LOGS, RADISH_LOGS, build_corpus
        from pipelines.bench.localise import localise_section, run_localise_bench
        from pipelines.bench.suites import ingest_to

        only = _corpus_logs(logs, datasets)
        with tempfile.TemporaryDirectory(prefix="gslam-bench-localise-in-") as tmp:
            # the corpus of the robustness suite: the Freiburg logs (real odometry) and the Radish logs with
            # odometry corrupted (odometry seed 0)
            corpus = [c for c in build_corpus(datasets, Path(tmp), 0) if only is None or c.name in only]
            missing = sorted(set(only or FREIBURG_LOGS + RADISH_LOGS) - {c.name for c in corpus})
            if missing:
                typer.echo(f"--datasets {datasets}: {', '.join(missing)} not found; left out", err=True)
            if not corpus:
                fail(f"--datasets {datasets}: no corpus log found")
            inputs = [(c.name, ingest_to(c.log, Path(tmp))) for c in corpus]
            runs = run_localise_bench(inputs, lambda s: typer.echo(s, err=True))
        text = localise_section(runs, command, machine_description(), versions())
    elif suite != "carpark":
        logs = [freiburg / "mit-csail.clf.gz", freiburg / "intel.clf.gz"]
        for log in logs:
            if not log.exists():
                fail(f"--freiburg {freiburg}: {log.name} not found")
        echo = lambda s: typer.echo(s, err=True)  # noqa: E731
        if suite == "freiburg":
            runs = run_suite("freiburg", logs, [30], list(range(seeds or 5)), [0], 1, echo)
            text = freiburg_section(runs, command, machine_description(), versions())
        else:
            if not data.exists():
                fail(f"--data {data}: no such file or directory")
            # Every core (the default), and one thread for the scaling; N 8 / 30 / 100 on the Car Park for
            # the growth in N; the Freiburg logs at N 30, as GMapping was measured.
            jobs = [(data, [8, 30, 100], [0]), (data, [30], [1]), (logs[0], [30], [0]), (logs[1], [30], [0, 1])]
            harness = gmapping if (gmapping / "run.sh").exists() else None
            if harness is None:
                echo(f"--gmapping {gmapping}: no run.sh there; the table gives GMapping's reference times")
            runs, gm_runs = [], []
            for log, ns, counts in jobs:
                runs += run_suite("speed", [log], ns, [0], counts, 3, echo, harness, gm_runs)
            text = speed_section(runs, command, machine_description(), versions(), 3, gm_runs)
    else:
        chosen = [m.strip() for m in methods.split(",") if m.strip()]
        if chosen == ["all"]:
            chosen = list(METHOD_NAMES)
        missing = [m for m in chosen if m not in METHOD_NAMES]
        if missing or not chosen:
            fail(
                f"--methods {methods}: unknown method(s) {', '.join(missing)}; "
                f"choose from {', '.join(METHOD_NAMES)} or all"
            )
        n_seeds = seeds if seeds is not None else (1 if quick else 3)
        grid = QUICK_GRID if quick else FULL_GRID
        if not data.exists():
            fail(f"--data {data}: no such file or directory")
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
        from mcaplog.tempfiles import write_atomic

        write_atomic(output, replace_section(output, suite, text))
        typer.echo(f"wrote {output}")
    else:
        typer.echo(text)


@app.command()
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


@app.command()
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


@app.command()
@guarded
def localise(
    map_path: Annotated[
        Path, typer.Argument(metavar="MAP", help="The map: a `gslam process` result .mcap or a map_server .yaml.")
    ],
    input_mcap: Annotated[Path, typer.Argument(metavar="IN", help="Ingested log (MCAP) with odometry and scans.")],
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
    recovery from kidnapping), with a tracking / lost state and a fitness score at every scan."""
    from gslam.localise import LocaliseConfig
    from pipelines.localise.run import LocaliseRequest, localise

    if initial_sigma is not None and initial_pose is None:
        fail("--initial-sigma needs --initial-pose")
    rrd_path = None if no_rrd else (rrd or output.with_suffix(".rrd"))
    outputs = {"OUT": output, **({"--rrd": rrd_path} if rrd_path is not None else {})}
    check_outputs(outputs, {"MAP": map_path, "IN": input_mcap})
    try:
        cfg = LocaliseConfig(seed=seed, max_particles=max_particles, global_particles=global_particles,
                             min_particles=min(100, max_particles))  # fmt: skip
    except ValueError as e:
        fail(str(e))
    request = LocaliseRequest(map_path, input_mcap, output, rrd_path, initial_pose, initial_sigma, cfg, skip_scans)
    with reporting("localise", "scans") as (report, _):
        summary = localise(request, report)
    typer.echo(f"map {summary.map_source}")
    typer.echo(summary.describe())
    typer.echo(f"wrote {output}" + (f" and {rrd_path}" if rrd_path is not None else ""))


def run() -> None:
    """The `gslam` console script: the typer app between two `startup.freeze_heap`: one before the
    command (the garbage collector's full passes while numba loads the compiled kernels then skip the
    modules imported so far), one on the way out, whatever the exit (the interpreter's teardown then
    skips numba's objects); docs/SPEED.md has what each saves."""
    from pipelines.run.startup import freeze_heap

    freeze_heap()  # the modules imported so far
    try:
        app()
    finally:
        freeze_heap()


if __name__ == "__main__":  # python -m pipelines.cli.app
    run()
