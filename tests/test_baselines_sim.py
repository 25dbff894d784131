"""Every method on the simulated Car Park-like world (poles with reflective tape, walls, parked cars)."""

from __future__ import annotations

import numpy as np
import pytest

from gslam.config import FilterConfig
from gslam.initialisation import dead_reckoning
from gslam.vehicle import VEHICLE_PRESETS
from ingest import ingest
from pipelines.demo.run import write_sydney_text
from pipelines.demo.world import SimConfig, simulate_sydney_log
from pipelines.evaluation.evaluate import read_result
from pipelines.process import process
from pipelines.run.input_log import InputLog
from pipelines.run.runner import RunConfig, SlamRunner

CAR = VEHICLE_PRESETS["carpark"]


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    sim = simulate_sydney_log(SimConfig(seed=2), CAR)
    ingest(write_sydney_text(sim, d / "log"), d / "sim.mcap")
    start = SlamRunner(InputLog(d / "sim.mcap"), RunConfig()).initial_pose
    dr = dead_reckoning(sim.drs, start, float(sim.gps[0, 0]), sim.truth[:, 0], CAR)
    dr_err = float(np.mean(np.hypot(*(dr[:, :2] - sim.truth[:, 1:3]).T)))
    return d / "sim.mcap", sim, dr_err


# Measured (sim seed 2, filter seed 0, N 8), mean distance to the true trajectory: dead reckoning 4.08 m;
# gslam 0.27, fastslam1 0.49, fastslam2 0.21, grid 0.44, grid-hr 0.47 m.
@pytest.mark.parametrize(
    "method,limit_m", [("gslam", 0.6), ("fastslam1", 0.8), ("fastslam2", 0.5), ("grid", 0.8), ("grid-hr", 0.8)]
)
def test_method_on_the_simulated_world(sim_log, tmp_path, method, limit_m):
    path, sim, dr_err = sim_log
    out = tmp_path / "r.mcap"
    process(path, out, None, RunConfig(filter=FilterConfig(seed=0, particles=8), method=method))
    res = read_result(out)
    err = float(np.mean(np.hypot(*(res.trajectory[:, :2] - sim.truth[: len(res.trajectory), 1:3]).T)))
    print(method, round(err, 3), round(dr_err, 3))
    assert err < limit_m, (method, err, dr_err)
    assert err < 0.3 * dr_err, (method, err, dr_err)
    assert len(res.map_p) > 5
