"""`gslam bench`'s suites behind one call: which suite runs what, on which logs, and the Markdown section it
gives (each suite's own module runs it and formats its table). Bad options raise `OptionError` naming the
option, before anything runs.

The peers' harnesses (`--gmapping`, `--lama`) are optional: a suite without one (no run.sh there, or LaMa
neither built nor buildable) says so in one line and runs without that peer."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pipelines.errors import OptionError
from pipelines.methods import NAMES as METHOD_NAMES

SUITES = ("carpark", "freiburg", "speed", "robustness", "localise", "continue")


@dataclass(frozen=True)
class BenchRequest:
    """What `gslam bench` was asked for (its options, with the command's defaults)."""

    suite: str = "carpark"
    quick: bool = False
    methods: str = "gslam"
    seeds: int | None = None
    data: Path = Path("../shared/datasets/carpark")
    freiburg: Path = Path("../shared/datasets/freiburg")
    gmapping: Path = Path("../shared/tools/gmapping")
    lama: Path = Path("../shared/tools/lama")
    datasets: Path = Path("../shared/datasets")
    logs: str | None = None
    command: str = "gslam bench"


def corpus_logs(logs: str | None, datasets: Path, more: tuple[str, ...] = ()) -> list[str] | None:
    """The corpus logs `--logs` names (None: all), checked against the corpus and the suite's `more` logs;
    and `--datasets` checked."""
    from pipelines.bench.corpus import FREIBURG_LOGS, radish_logs

    known = [*FREIBURG_LOGS, *radish_logs(datasets), *more]
    only = [name.strip() for name in logs.split(",") if name.strip()] if logs else None
    unknown = sorted(set(only or []) - set(known))
    if unknown:
        raise OptionError(f"--logs: unknown log(s) {', '.join(unknown)}; the logs: {', '.join(known)}")
    if not datasets.is_dir():
        raise OptionError(f"--datasets {datasets}: no such directory")
    return only


def check_request(request: BenchRequest) -> None:
    """Refuse an unknown suite or method before anything runs."""
    if request.suite not in SUITES:
        raise OptionError(f"--suite {request.suite}: expected {', '.join(SUITES[:-1])} or {SUITES[-1]}")
    if request.suite == "carpark":
        chosen_methods(request.methods)


def chosen_methods(methods: str) -> list[str]:
    """The methods `--methods` names (`all`: every one)."""
    chosen = [m.strip() for m in methods.split(",") if m.strip()]
    if chosen == ["all"]:
        return list(METHOD_NAMES)
    missing = [m for m in chosen if m not in METHOD_NAMES]
    if missing or not chosen:
        raise OptionError(
            f"--methods {methods}: unknown method(s) {', '.join(missing)}; choose from {', '.join(METHOD_NAMES)} or all"
        )
    return chosen


def run_benchmark(request: BenchRequest, echo: Callable[[str], None]) -> str:
    """Run the suite `request` names; its Markdown section (with the machine, versions and command).
    `echo` takes the progress lines."""
    check_request(request)
    run = {
        "robustness": _robustness,
        "localise": _localise,
        "continue": _continue,
        "freiburg": _freiburg,
        "speed": _speed,
        "carpark": _carpark,
    }[request.suite]
    return run(request, echo)


def _machine():
    from pipelines.bench.carpark import machine_description, versions

    return machine_description(), versions()


def _gmapping_harness(request: BenchRequest, echo: Callable[[str], None], without: str) -> Path | None:
    if (request.gmapping / "run.sh").exists():
        return request.gmapping
    echo(f"--gmapping {request.gmapping}: no run.sh there; {without}")
    return None


def _lama_harness(request: BenchRequest, echo: Callable[[str], None]) -> Path | None:
    """LaMa's harness directory, or None (said in one line) when it has no run.sh, or when LaMa is not built
    and `LAMA_MIRROR` (the git dir of iris-ua/iris_lama the harness builds it from) is not set."""
    import os

    from pipelines.bench.lama import lama_build_dir, lama_built

    if not (request.lama / "run.sh").exists():
        echo(f"--lama {request.lama}: no run.sh there; LaMa is left out")
        return None
    if not lama_built(request.lama) and not os.environ.get("LAMA_MIRROR"):
        echo(
            f"--lama {request.lama}: LaMa is not built ({lama_build_dir() / 'bin' / 'lama_driver'}, or it is older "
            "than the harness's driver.cpp) and LAMA_MIRROR (a git dir of iris-ua/iris_lama to build it from) is "
            "not set; LaMa is left out"
        )
        return None
    return request.lama


def _robustness(request: BenchRequest, echo: Callable[[str], None]) -> str:
    from pipelines.bench.robustness import robustness_section, run_robustness

    only = corpus_logs(request.logs, request.datasets)
    harness = _gmapping_harness(request, echo, "GMapping is left out")
    lama = _lama_harness(request, echo)
    seeds = list(range(request.seeds or 3))
    results = run_robustness(request.datasets, seeds, echo, harness, only=only, lama=lama)
    return robustness_section(results, request.command, *_machine(), 30, 0)


def _localise(request: BenchRequest, echo: Callable[[str], None]) -> str:
    from pipelines.bench.corpus import FREIBURG_LOGS, build_corpus, radish_logs
    from pipelines.bench.localise import localise_section, run_localise_bench
    from pipelines.bench.suites import ingest_to

    only = corpus_logs(request.logs, request.datasets)
    with tempfile.TemporaryDirectory(prefix="gslam-bench-localise-in-") as tmp:
        # the corpus of the robustness suite: the Freiburg logs (real odometry) and the Radish logs with
        # odometry corrupted (odometry seed 0)
        corpus = [c for c in build_corpus(request.datasets, Path(tmp), 0) if only is None or c.name in only]
        missing = sorted(set(only or FREIBURG_LOGS + radish_logs(request.datasets)) - {c.name for c in corpus})
        if missing:
            echo(f"--datasets {request.datasets}: {', '.join(missing)} not found; left out")
        if not corpus:
            raise OptionError(f"--datasets {request.datasets}: no corpus log found")
        inputs = [(c.name, ingest_to(c.log, Path(tmp))) for c in corpus]
        runs = run_localise_bench(inputs, echo)
    return localise_section(runs, request.command, *_machine())


def _continue(request: BenchRequest, echo: Callable[[str], None]) -> str:
    from pipelines.bench.continuation import continue_section, run_continue_bench
    from pipelines.bench.corpus import build_corpus
    from pipelines.bench.suites import ingest_to

    only = corpus_logs(request.logs, request.datasets, ("carpark",))
    with tempfile.TemporaryDirectory(prefix="gslam-bench-continue-in-") as tmp:
        corpus = [c for c in build_corpus(request.datasets, Path(tmp), 0) if only is None or c.name in only]
        inputs = [(c.name, ingest_to(c.log, Path(tmp))) for c in corpus]
        carpark = request.datasets / "carpark"  # the paper's log, scored by its GPS
        if only is None or "carpark" in only:
            if carpark.is_dir():
                inputs.append(("carpark", ingest_to(carpark, Path(tmp))))
            else:
                echo(f"--datasets {request.datasets}: carpark not found; left out")
        if not inputs:
            raise OptionError(f"--datasets {request.datasets}: no corpus log found")
        runs = run_continue_bench(inputs, list(range(request.seeds or 1)), echo)
    return continue_section(runs, request.command, *_machine())


def _freiburg_logs(request: BenchRequest) -> list[Path]:
    logs = [request.freiburg / "mit-csail.clf.gz", request.freiburg / "intel.clf.gz"]
    for log in logs:
        if not log.exists():
            raise OptionError(f"--freiburg {request.freiburg}: {log.name} not found")
    return logs


def _freiburg(request: BenchRequest, echo: Callable[[str], None]) -> str:
    from pipelines.bench.lama import LamaRun
    from pipelines.bench.suites import freiburg_section, run_suite

    logs = _freiburg_logs(request)
    lama = _lama_harness(request, echo)
    lama_runs: list[LamaRun] = []
    seeds = list(range(request.seeds or 5))
    runs = run_suite("freiburg", logs, [30], seeds, [0], 1, echo, lama=lama, lama_runs=lama_runs)
    return freiburg_section(runs, request.command, *_machine(), lama_runs)


def _speed(request: BenchRequest, echo: Callable[[str], None]) -> str:
    from pipelines.bench.corpus import build_corpus
    from pipelines.bench.suites import backend_cost_runs, backend_cost_section, run_suite, speed_section

    logs = _freiburg_logs(request)
    if not request.data.exists():
        raise OptionError(f"--data {request.data}: no such file or directory")
    # Every core (the default), and one thread for the scaling; N 8 / 30 / 100 on the Car Park for the
    # growth in N; the Freiburg logs at N 30, as GMapping was measured.
    jobs = [(request.data, [8, 30, 100], [0]), (request.data, [30], [1]), (logs[0], [30], [0]), (logs[1], [30], [0, 1])]
    harness = _gmapping_harness(request, echo, "the table gives GMapping's reference times")
    lama = _lama_harness(request, echo)
    runs, gm_runs, lama_runs = [], [], []
    for log, ns, counts in jobs:
        before = len(lama_runs)
        runs += run_suite("speed", [log], ns, [0], counts, 3, echo, harness, gm_runs, lama, lama_runs)
        if lama is not None and 30 in ns and 0 in counts and len(lama_runs) == before:
            lama = None  # it failed, and said why: not again for the next logs
    text = speed_section(runs, request.command, *_machine(), 3, gm_runs, lama_runs)
    # The back end's cost on intel and the 1.75 km campus (the robustness corpus's, odometry seed 0)
    with tempfile.TemporaryDirectory(prefix="gslam-bench-speed-") as tmp:
        campus = [c.log for c in build_corpus(request.datasets, Path(tmp), 0) if c.name == "freiburg-campus"]
        if not campus:
            echo(f"--datasets {request.datasets}: freiburg-campus not found; the back end's cost on intel only")
        pairs = backend_cost_runs([logs[1], *campus], 3, echo, Path(tmp))
    return text + backend_cost_section(pairs)


def _carpark(request: BenchRequest, echo: Callable[[str], None]) -> str:
    from pipelines.bench.carpark import FULL_GRID, QUICK_GRID, markdown_table, run_bench

    t0 = time.perf_counter()
    chosen = chosen_methods(request.methods)
    n_seeds = request.seeds if request.seeds is not None else (1 if request.quick else 3)
    grid = QUICK_GRID if request.quick else FULL_GRID
    if not request.data.exists():
        raise OptionError(f"--data {request.data}: no such file or directory")
    with tempfile.TemporaryDirectory(prefix="gslam-bench-in-") as tmp:
        if request.data.is_dir():
            from pipelines.bench.suites import ingest_to

            input_mcap = ingest_to(request.data, Path(tmp))
        else:
            input_mcap = request.data
        results = run_bench(input_mcap, grid, n_seeds, progress=echo, methods=tuple(chosen))
    return markdown_table(results, n_seeds, request.command, time.perf_counter() - t0)
