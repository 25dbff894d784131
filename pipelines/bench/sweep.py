"""`gslam sweep`: many logs x methods x N x M x seeds x options, on a process pool or a Dask cluster.

Each task runs `process` + `eval` and writes, under RESULTS_DIR/tasks/<task id>/, its log, optionally
its result MCAP, and last its `metrics.json` (atomically): a task whose metrics.json says "ok" is
complete, so `--resume` skips it and an interrupted sweep loses no finished result. A task that raises
is recorded with its error ("failed") and the sweep goes on. The results table (CSV and markdown)
aggregates mean and spread over seeds.
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import json
import multiprocessing
import os
import statistics
import time
import traceback
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gslam import __version__
from mcaplog.tempfiles import write_atomic
from pipelines.methods import NAMES as METHODS

SWEEP_FILES = ("results.csv", "results.md", "sweep.json")
"""What a sweep writes at the top of its results directory (besides tasks/)."""
SPEC_KEYS = {"inputs", "methods", "particles", "points", "seeds", "options", "keep_results", "rrd"}


@dataclass
class SweepSpec:
    """A sweep: every combination of inputs x methods x particles x points x seeds x option values."""

    inputs: list[str]
    methods: list[str] = field(default_factory=lambda: ["gslam"])
    particles: list[int] = field(default_factory=lambda: [8])
    points: list[int] = field(default_factory=lambda: [10])
    seeds: list[int] = field(default_factory=lambda: [0])
    options: dict[str, list[Any]] = field(default_factory=dict)
    keep_results: bool = False
    """Keep each task's result MCAP (else only metrics and log)."""
    rrd: bool = False
    """Also write each task's Rerun recording (with keep_results)."""

    @classmethod
    def load(cls, path: Path) -> SweepSpec:
        """Read and check a spec: every value is checked as the filter option it becomes, and a bad
        one is refused naming the file and line (no task is started)."""
        from pipelines.errors import OptionError
        from pipelines.run.options import Setting, filter_config, load_toml, where_in_toml

        data, text = load_toml(path, "sweep spec")
        unknown = sorted(set(data) - SPEC_KEYS)
        if unknown:
            where = where_in_toml(path, text, None, unknown[0])
            raise OptionError(f"{where}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(SPEC_KEYS))}")
        if "inputs" not in data:
            raise OptionError(f"{path}: 'inputs' (a list of MCAP paths) is required")
        options = data.get("options", {})
        if not isinstance(options, dict):
            raise OptionError(f"{where_in_toml(path, text, None, 'options')}: 'options' must be an [options] table")

        def as_list(v):
            return v if isinstance(v, list) else [v]

        def where(key: str, table: str | None = None) -> str:
            return where_in_toml(path, text, table, key)

        checks = [("particles", "particles"), ("points", "points_per_observation"), ("seeds", "seed")]
        for key, option in checks:  # each task's N, M and seed come from the top-level axes only
            if option in options or key in options:
                name = option if option in options else key
                raise OptionError(
                    f"{where(name, 'options')}: {name} in [options] would be ignored; give it as the "
                    f"top-level key '{key}' (a list)"
                )
        for key, option in checks:
            filter_config([Setting(option, v, where(key)) for v in as_list(data.get(key, []))])
        for key, values in options.items():
            filter_config([Setting(key, v, where(key, "options")) for v in as_list(values)])
        for key in ("keep_results", "rrd"):
            if not isinstance(data.get(key, False), bool):
                raise OptionError(f"{where(key)}: {key} must be true or false, got {data[key]!r}")
        inputs = as_list(data["inputs"])
        if not all(isinstance(p, str) for p in inputs):
            raise OptionError(f"{where('inputs')}: inputs must be a list of paths (strings), got {data['inputs']!r}")
        bad = [m for m in as_list(data.get("methods", [])) if m not in METHODS]
        if bad:
            raise OptionError(
                f"{where('methods')}: method(s) {', '.join(map(str, bad))} not available; "
                f"available: {', '.join(METHODS)}"
            )
        base = Path(path).parent
        _check_axis(where("inputs"), "inputs", inputs, [os.path.normpath(base / p) for p in inputs])
        axes = [(key, None, as_list(data[key])) for key in ("methods", "particles", "points", "seeds") if key in data]
        axes += [(key, "options", as_list(values)) for key, values in options.items()]
        for key, table, values in axes:
            _check_axis(where(key, table), key if table is None else f"[{table}] {key}", values)
        return cls(
            inputs=[str(p if Path(p).is_absolute() else (base / p)) for p in inputs],
            methods=as_list(data.get("methods", ["gslam"])),
            particles=as_list(data.get("particles", [8])),
            points=as_list(data.get("points", [10])),
            seeds=as_list(data.get("seeds", [0])),
            options={k: as_list(v) for k, v in options.items()},
            keep_results=data.get("keep_results", False),
            rrd=data.get("rrd", False),
        )

    def tasks(self) -> list[dict[str, Any]]:
        """Every combination of the axes, each a task dict with its `task_id`."""
        names = sorted(self.options)
        out = []
        for inp, method, n, m, combo, seed in itertools.product(
            self.inputs,
            self.methods,
            self.particles,
            self.points,
            itertools.product(*(self.options[k] for k in names)),
            self.seeds,
        ):
            options = dict(zip(names, combo, strict=True))
            task = {
                "input": inp,
                "method": method,
                "particles": n,
                "points": m,
                "seed": seed,
                "options": options,
                "keep_results": self.keep_results,
                "rrd": self.rrd,
            }
            task["id"] = task_id(task)
            out.append(task)
        return out


def _check_axis(where: str, name: str, values: list[Any], same: list[str] | None = None) -> None:
    """Refuse an axis of the sweep that is an empty list (the product would have no task, and the sweep would
    write an empty table as if it had run) or that lists a value twice (the two tasks would have one task id
    and write the same directory at once). `same[i]` says what `values[i]` stands for (default: its JSON)."""
    from pipelines.errors import OptionError

    if not values:
        leave = " (or leave the key out)" if name != "inputs" else ""
        raise OptionError(f"{where}: '{name}' is an empty list; give at least one value{leave}")
    seen: set[str] = set()
    for i, v in enumerate(values):
        key = same[i] if same is not None else json.dumps(v, sort_keys=True, default=str)
        if key in seen:
            raise OptionError(f"{where}: '{name}' lists {v!r} twice; each value may appear once")
        seen.add(key)


def task_id(task: dict[str, Any]) -> str:
    """A readable, stable name: input stem, method, N, M, seed, and a hash of everything."""
    key = json.dumps(
        {k: task[k] for k in ("input", "method", "particles", "points", "seed", "options")}, sort_keys=True
    )
    digest = hashlib.sha1(key.encode()).hexdigest()[:8]
    cell = f"n{task['particles']}_m{task['points']}_s{task['seed']}"
    return f"{Path(task['input']).stem}__{task['method']}__{cell}__{digest}"


def run_task(task: dict[str, Any], results_dir: str) -> dict[str, Any]:
    """Run one task (in a worker process): process + eval; never raises, the record says what happened."""
    from pipelines.bench.tasks import Task
    from pipelines.bench.tasks import run_task as run_one

    out_dir = Path(results_dir) / "tasks" / task["id"]
    out_dir.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {
        "task": task,
        "gslam_version": __version__,
        "host": os.uname().nodename,
        "pid": os.getpid(),
        "malloc_trim_threshold": os.environ.get("MALLOC_TRIM_THRESHOLD_"),
    }
    log = io.StringIO()
    t0 = time.perf_counter()
    result_path = out_dir / "result.mcap"
    try:
        with redirect_stdout(log), redirect_stderr(log):
            rrd = result_path.with_suffix(".rrd") if task.get("rrd") and task.get("keep_results") else None
            run = run_one(Task.of(task), result_path, rrd, command=f"gslam sweep task {task['id']}", keep=True)
        record.update(status="ok", metrics=run.metrics, steps=run.result["steps"])
    except BaseException as e:  # recorded, not raised: one failing task must not stop the sweep
        if isinstance(e, KeyboardInterrupt):
            raise
        record.update(status="failed", error=f"{type(e).__name__}: {e}", traceback=traceback.format_exc())
    finally:
        record["wall_s"] = time.perf_counter() - t0
        if not task.get("keep_results"):
            result_path.unlink(missing_ok=True)
        (out_dir / "log.txt").write_text(log.getvalue() + record.get("traceback", ""))
    write_atomic(out_dir / "metrics.json", json.dumps(record, indent=2))
    return record


def completed(results_dir: Path, task: dict[str, Any]) -> dict[str, Any] | None:
    """The record of a task that finished "ok" before, else None."""
    path = Path(results_dir) / "tasks" / task["id"] / "metrics.json"
    try:
        record = json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None
    return record if record.get("status") == "ok" else None


@contextmanager
def executor_for(workers: int, scheduler: str | None):
    """A local process pool, or a Dask cluster's executor when a scheduler address is given."""
    if scheduler:
        try:
            import dask
            from distributed import Client
        except ImportError:
            raise ValueError(
                "a Dask scheduler was given but Dask is not installed: pip install 'gslam[dask]'"
            ) from None
        # Workers our own nannies spawn must not get MALLOC_TRIM_THRESHOLD_ (it made numpy 3-4x slower here);
        # for an external cluster, set the same in its workers' Dask config (docs/SWEEP.md).
        dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None})
        client = Client(scheduler, timeout="20s")
        try:
            yield client.get_executor(pure=False)
        finally:
            client.close()
    else:
        # Fresh interpreters, not forks: the filter's compiled loops run on a thread pool, and a fork of a
        # process whose pool has started inherits locks that no thread will release.
        pool = ProcessPoolExecutor(
            max_workers=workers, mp_context=multiprocessing.get_context("spawn"), initializer=_worker_start
        )
        try:
            yield pool
        except BaseException:  # Ctrl-C, SIGTERM, an error: the workers end with the sweep, not after it
            for proc in list(getattr(pool, "_processes", {}).values()):
                proc.terminate()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        pool.shutdown(wait=True)


def _worker_start() -> None:
    """In each local worker: leave Ctrl-C to the sweep (which ends the workers), and end when the sweep's
    process does, even killed (Linux: the parent-death signal)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass  # not Linux: the pool's own checks end idle workers when the sweep is gone
    if os.getppid() == 1:  # the sweep ended before the signal was set
        os._exit(0)


@dataclass
class SweepReport:
    records: list[dict[str, Any]]
    skipped: int
    failed: int
    wall_s: float
    csv_path: Path
    md_path: Path


def run_sweep(
    spec: SweepSpec,
    results_dir: Path,
    workers: int = 2,
    scheduler: str | None = None,
    resume: bool = False,
    progress: Callable[[int, int, dict[str, Any]], None] | None = None,
) -> SweepReport:
    results_dir = Path(results_dir)
    (results_dir / "tasks").mkdir(parents=True, exist_ok=True)
    tasks = spec.tasks()
    records: list[dict[str, Any]] = []
    todo = []
    for task in tasks:
        done = completed(results_dir, task) if resume else None
        if done is not None:
            records.append(done)
        else:
            todo.append(task)
    skipped = len(records)
    t0 = time.perf_counter()
    if progress is not None:
        progress(skipped, len(tasks), {})
    if todo:
        with executor_for(workers, scheduler) as ex:
            futures: dict[Future, dict[str, Any]] = {ex.submit(run_task, t, str(results_dir)): t for t in todo}
            try:
                for fut in as_completed(futures):
                    try:
                        rec = fut.result()
                    except Exception as e:  # the worker itself died
                        rec = {"task": futures[fut], "status": "failed", "error": f"{type(e).__name__}: {e}"}
                    records.append(rec)
                    if progress is not None:
                        progress(len(records), len(tasks), rec)
            except KeyboardInterrupt:
                for fut in futures:
                    fut.cancel()
                raise
    wall = time.perf_counter() - t0
    order = {t["id"]: i for i, t in enumerate(tasks)}
    records.sort(key=lambda r: order.get(r["task"]["id"], 0))
    csv_path, md_path = write_tables(records, results_dir, spec)
    write_atomic(
        results_dir / "sweep.json",
        json.dumps(
            {
                "gslam_version": __version__,
                "wall_s": wall,
                "workers": workers,
                "scheduler": scheduler,
                "tasks": len(tasks),
                "skipped": skipped,
                "failed": sum(r["status"] != "ok" for r in records),
            },
            indent=2,
        ),
    )
    return SweepReport(records, skipped, sum(r["status"] != "ok" for r in records), wall, csv_path, md_path)


AGG_METRICS = (
    "gps_mean_error_m",
    "gps_mean_error_online_m",
    "gps_rmse_aligned_m",
    "relations_trans_m",
    "pole_map_error_m",
    "ms_per_step_median",
    "final_map_points",
)


def _group_key(task: dict[str, Any]) -> tuple:
    return (
        Path(task["input"]).stem,
        task["method"],
        task["particles"],
        task["points"],
        json.dumps(task["options"], sort_keys=True),
    )


def aggregate(records: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per configuration: mean and standard deviation of each metric over the seeds that ran ok."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in records:
        groups.setdefault(_group_key(r["task"]), []).append(r)
    rows = []
    for (inp, method, n, m, options), recs in groups.items():
        ok = [r for r in recs if r["status"] == "ok"]
        row: dict[str, Any] = {
            "input": inp,
            "method": method,
            "particles": n,
            "points": m,
            "options": options,
            "seeds_ok": len(ok),
            "seeds_failed": len(recs) - len(ok),
        }
        for k in AGG_METRICS:
            vals = [r["metrics"][k] for r in ok if r["metrics"].get(k) is not None]
            row[f"{k}_mean"] = statistics.mean(vals) if vals else None
            row[f"{k}_std"] = statistics.stdev(vals) if len(vals) > 1 else (0.0 if vals else None)
        rows.append(row)
    return rows


def write_tables(records: list[dict[str, Any]], results_dir: Path, spec: SweepSpec) -> tuple[Path, Path]:
    rows = aggregate(records)
    buf = io.StringIO()
    if rows:
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    csv_path = results_dir / "results.csv"
    write_atomic(csv_path, buf.getvalue())

    def fmt(row, k, digits=3):
        mean, sd = row[f"{k}_mean"], row[f"{k}_std"]
        return "-" if mean is None else f"{mean:.{digits}f} ± {sd:.{digits}f}"

    lines = [
        "# Sweep results",
        "",
        f"{len(records)} tasks; mean ± standard deviation over seeds.",
        "",
        "| input | method | N | M | options | seeds ok / failed | GPS error (m) | relations (m) "
        "| ms/step | map points |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['input']} | {r['method']} | {r['particles']} | {r['points']} | `{r['options']}` "
            f"| {r['seeds_ok']} / {r['seeds_failed']} | {fmt(r, 'gps_mean_error_m')} "
            f"| {fmt(r, 'relations_trans_m')} | {fmt(r, 'ms_per_step_median', 1)} "
            f"| {fmt(r, 'final_map_points', 0)} |"
        )
    failed = [r for r in records if r["status"] != "ok"]
    if failed:
        lines += ["", "## Failed tasks", ""] + [f"- `{r['task']['id']}`: {r.get('error', '?')}" for r in failed]
    md_path = results_dir / "results.md"
    write_atomic(md_path, "\n".join(lines) + "\n")
    return csv_path, md_path
