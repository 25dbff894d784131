"""One task runner for bench, its suites and sweep: a `Task` (input, method, N, M, seed, filter options)
is run by `gslam process` and scored by `gslam eval`, in this process or as a child process."""

from __future__ import annotations

import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gslam.config import FilterConfig


@dataclass(frozen=True)
class Task:
    input: Path
    method: str = "gslam"
    particles: int = FilterConfig.particles
    points: int = FilterConfig.points_per_observation
    seed: int = 0
    options: dict[str, Any] = field(default_factory=dict)
    """Filter options (FilterConfig names) besides N, M and the seed."""
    threads: int | None = None
    """Threads of the compiled loops (None: every core)."""

    @classmethod
    def of(cls, record: dict[str, Any]) -> Task:
        """A task from a sweep's task record (`pipelines.bench.sweep`)."""
        return cls(
            Path(record["input"]),
            record.get("method", "gslam"),
            record["particles"],
            record["points"],
            record["seed"],
            dict(record.get("options", {})),
        )

    def filter_config(self) -> FilterConfig:
        opts = dict(self.options, particles=self.particles, points_per_observation=self.points, seed=self.seed)
        return FilterConfig.from_dict(opts)

    def run_config(self):  # -> RunConfig (imported here: the runner imports numpy)
        from pipelines.run.runner import RunConfig

        return RunConfig(filter=self.filter_config(), method=self.method, threads=self.threads)

    def command(self, output: Path, rrd: Path | None) -> list[str]:
        """The `gslam process` command line that runs this task (`python -m pipelines.cli`)."""
        cmd = [sys.executable, "-P", "-m", "pipelines.cli", "process", str(self.input), str(output)]
        cmd += ["--particles", str(self.particles), "--seed", str(self.seed)]
        if self.points != FilterConfig.points_per_observation:
            cmd += ["--points", str(self.points)]
        if self.method != "gslam":
            cmd += ["--method", self.method]
        if self.threads:
            cmd += ["--threads", str(self.threads)]
        for name, value in self.options.items():
            cmd += ["--set", f"{name}={_toml_value(value)}"]
        cmd += ["--rrd", str(rrd)] if rrd is not None else ["--no-rrd"]
        return cmd


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


@dataclass
class TaskResult:
    task: Task
    output: Path
    metrics: dict[str, Any]
    """`gslam eval`'s metrics of the result."""
    result: dict[str, Any]
    """The result's own record (its "result" metadata: steps, times, peak memory)."""
    wall_s: float
    """The run's wall time: `process` alone, or the whole child process (import to exit)."""


def run_task(
    task: Task,
    output: Path,
    rrd: Path | None = None,
    *,
    command: str = "gslam bench",
    child_process: bool = False,
    keep: bool = False,
) -> TaskResult:
    """Run `task` into `output` (and the recording `rrd`), then evaluate it against its input. In this
    process by default (`command` is what the result records), or as the `gslam process` child a user
    would run (`child_process`, timed whole). The outputs are removed afterwards unless `keep`."""
    from pipelines.evaluation.evaluate import evaluate_result, read_result

    output = Path(output)
    t0 = time.perf_counter()
    try:
        if child_process:
            cmd = task.command(output, rrd)
            proc = subprocess.run(cmd, capture_output=True, text=True)
            wall = time.perf_counter() - t0
            if proc.returncode != 0:
                last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
                raise RuntimeError(f"{' '.join(cmd)} failed: {last}")
        else:
            from pipelines.process import process

            process(task.input, output, rrd, task.run_config(), command=command)
            wall = time.perf_counter() - t0
        metrics = evaluate_result(output, task.input)
        result = dict(read_result(output).metadata["result"])
    finally:
        if not keep:
            for p in (output, rrd):
                if p is not None:
                    Path(p).unlink(missing_ok=True)
    return TaskResult(task, output, metrics, result, wall)
