"""`gslam bench`: benchmarks into docs/BENCHMARKS.md."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli.common import check_outputs, invocation
from pipelines.cli.errors import guarded
from pipelines.methods import NAMES as METHOD_NAMES


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
            "localise: `gslam localise` in maps `gslam process` built (global, wrong start, half map, kidnap); "
            "continue: each corpus log's second half continued from its first half's result (--continue).",
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
    lama: Annotated[
        Path,
        typer.Option(
            "--lama",
            help="IRIS LaMa harness directory (freiburg, speed and robustness suites): LaMa PF-SLAM and Slam2D run "
            "beside gslam; it builds LaMa once from LAMA_MIRROR (a git dir of iris-ua/iris_lama) when "
            "/tmp/lama is absent. Without it (or when it cannot build or run) LaMa is left out.",
        ),
    ] = Path("../shared/tools/lama"),
    datasets: Annotated[
        Path,
        typer.Option(
            "--datasets", help="The datasets directory (robustness, localise and continue suites: the corpus)."
        ),
    ] = Path("../shared/datasets"),
    logs: Annotated[
        str | None,
        typer.Option(
            "--logs",
            help="Robustness, localise and continue suites: comma-separated corpus logs to run (default: all).",
        ),
    ] = None,
) -> None:
    """Benchmarks into docs/BENCHMARKS.md: the paper's Tables 3 and 4 on the Car Park log (beside the paper's
    figures), the Freiburg indoor logs (beside GMapping and IRIS LaMa), speed, and the robustness corpus."""
    from pipelines.bench.dispatch import BenchRequest, check_request, run_benchmark

    request = BenchRequest(
        suite=suite,
        quick=quick,
        methods=methods,
        seeds=seeds,
        data=data,
        freiburg=freiburg,
        gmapping=gmapping,
        lama=lama,
        datasets=datasets,
        logs=logs,
        command=invocation(ctx),
    )
    check_request(request)
    if output is not None:
        check_outputs({"-o": output}, {"--data": data, "--freiburg": freiburg, "--datasets": datasets})
    text = run_benchmark(request, lambda line: typer.echo(line, err=True))
    if output is not None:
        from mcaplog.tempfiles import write_atomic
        from pipelines.bench.suites import replace_section

        write_atomic(output, replace_section(output, suite, text))
        typer.echo(f"wrote {output}")
    else:
        typer.echo(text)
