"""One registry of methods (`pipelines.methods`): the command line, the runner, bench and sweep read it,
and a method added to it is usable by all of them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipelines import methods
from pipelines.methods import NAMES, Method


def test_every_reader_offers_exactly_the_registry():
    from pipelines.bench.sweep import METHODS as SWEEP_METHODS
    from pipelines.cli.common import Method as CliMethod

    assert tuple(m.value for m in CliMethod) == NAMES
    assert tuple(SWEEP_METHODS) == NAMES
    assert NAMES == ("gslam", "fastslam1", "fastslam2", "grid", "grid-hr", "odometry")


def test_the_runner_refuses_a_method_not_registered():
    from pipelines.run.runner import RunConfig

    with pytest.raises(ValueError, match="method must be one of gslam, fastslam1"):
        RunConfig(method="ekf")


def test_a_method_added_to_the_registry_is_run_by_the_runner(monkeypatch):
    """A new baseline is its module plus one registry line: nothing else has to learn its name."""
    from gslam.baselines.fastslam import FastSlamFilter
    from pipelines.run.runner import RunConfig

    built = []

    def build(cfg, pose, min_range_m):
        built.append((cfg.filter.particles, min_range_m))
        return methods.METHODS["fastslam1"].build(cfg, pose, min_range_m)

    extra = Method("fastslam-alias", "FastSLAM 1.0 under another name", build)
    monkeypatch.setitem(methods.METHODS, extra.name, extra)
    cfg = RunConfig(method="fastslam-alias")
    flt = methods.make_filter(dataclasses.replace(cfg), np.zeros(3), 0.5)
    assert isinstance(flt, FastSlamFilter) and built == [(cfg.filter.particles, 0.5)]


def test_sweep_tasks_run_the_method_they_name(tmp_path):
    """A sweep's method reaches the run (it was dropped: every task ran G-SLAM)."""
    from pipelines.bench.sweep import SweepSpec
    from pipelines.bench.tasks import Task

    spec_path = tmp_path / "s.toml"
    spec_path.write_text('inputs = ["in.mcap"]\nmethods = ["fastslam2", "grid"]\nparticles = [4]\n')
    tasks = SweepSpec.load(spec_path).tasks()
    assert [Task.of(t).run_config().method for t in tasks] == ["fastslam2", "grid"]
    assert [Task.of(t).run_config().filter.particles for t in tasks] == [4, 4]


def test_a_sweep_task_hands_its_method_to_the_run(tmp_path, monkeypatch):
    from pipelines.bench import sweep, tasks

    seen = []

    def fake_run(task, output, rrd=None, **kwargs):
        seen.append(task.run_config().method)
        return tasks.TaskResult(task, output, {"gps_mean_error_m": 0.0}, {"steps": 1}, 0.0)

    monkeypatch.setattr(tasks, "run_task", fake_run)
    spec_path = tmp_path / "s.toml"
    spec_path.write_text('inputs = ["in.mcap"]\nmethods = ["grid-hr"]\n')
    (task,) = sweep.SweepSpec.load(spec_path).tasks()
    record = sweep.run_task(task, str(tmp_path / "out"))
    assert record["status"] == "ok" and seen == ["grid-hr"]
