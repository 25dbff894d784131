"""`gslam sweep`: local pool and a local Dask cluster agree; failures are recorded; resume works."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipelines.bench.sweep import SweepSpec, run_sweep

METRICS = ("gps_mean_error_m", "gps_rmse_aligned_m", "final_map_points")


def write_spec(path: Path, inputs: list[Path], seeds=(0, 1), particles=(2,), extra: str = "") -> Path:
    path.write_text(
        f"inputs = {json.dumps([str(p) for p in inputs])}\nparticles = {list(particles)}\npoints = [4]\n"
        f"seeds = {list(seeds)}\n{extra}"
    )
    return path


def by_id(records):
    return {r["task"]["id"]: r for r in records}


def test_local_pool_and_dask_agree_and_failures_are_recorded(carpark_mcap, tmp_path):
    pytest.importorskip("distributed")
    from distributed import LocalCluster

    spec = SweepSpec.load(
        write_spec(
            tmp_path / "s.toml",
            [carpark_mcap, tmp_path / "missing.mcap"],
            extra="[options]\nweight_tempering = [0.3, 0.5]\n",
        )
    )
    assert len(spec.tasks()) == 2 * 2 * 2
    local = run_sweep(spec, tmp_path / "local", workers=2)
    assert local.failed == 4  # every task on the missing input, and only those
    for r in local.records:
        assert (r["status"] == "ok") == ("missing" not in r["task"]["input"])
        if r["status"] == "failed":
            assert "missing.mcap" in r["error"]
    import dask

    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            remote = run_sweep(spec, tmp_path / "dask", scheduler=cluster.scheduler_address)
    a, b = by_id(local.records), by_id(remote.records)
    assert a.keys() == b.keys()
    for k, ra in a.items():
        assert ra["status"] == b[k]["status"]
        if ra["status"] == "ok":
            for m in METRICS:
                assert ra["metrics"][m] == b[k]["metrics"][m], (k, m)
            assert b[k]["malloc_trim_threshold"] is None  # unset on our workers
    rows = (tmp_path / "local" / "results.csv").read_text().splitlines()
    assert len(rows) == 1 + 4  # header + (2 inputs x 2 option values)
    assert "Failed tasks" in (tmp_path / "local" / "results.md").read_text()


def test_resume_after_killing_a_sweep(carpark_mcap, tmp_path):
    spec_path = write_spec(tmp_path / "s.toml", [carpark_mcap], seeds=(0, 1, 2, 3), particles=(2, 3))
    out = tmp_path / "out"
    env = dict(os.environ, GSLAM_PROGRESS="")
    cmd = [sys.executable, "-m", "pipelines.cli", "sweep", str(spec_path), "-o", str(out), "--workers", "1"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 120
    while time.time() < deadline and len(list(out.glob("tasks/*/metrics.json"))) < 2:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    finished = {p.parent.name for p in out.glob("tasks/*/metrics.json")}
    assert 2 <= len(finished) < 8, "the sweep should have been killed part-way"
    for p in out.glob("tasks/*/metrics.json"):
        assert json.loads(p.read_text())["status"] == "ok"  # complete files only (atomic writes)
    report = run_sweep(SweepSpec.load(spec_path), out, workers=2, resume=True)
    assert report.skipped == len(finished)
    assert len(report.records) == 8 and report.failed == 0
