"""Run options: every one may come from a TOML file and is recorded in the result's configuration."""

from __future__ import annotations

import dataclasses

from pipelines.run.options import run_config
from pipelines.run.runner import RunConfig


def test_every_run_option_is_known_to_toml_and_recorded(tmp_path):
    config = tmp_path / "c.toml"
    config.write_text('method = "grid"\ngrid_cells = 500\nthreads = 1\n[filter]\nparticles = 4\n')
    cfg = run_config(config, [], [])
    assert (cfg.method, cfg.grid_cells, cfg.threads, cfg.filter.particles) == ("grid", 500, 1, 4)
    recorded = cfg.as_dict()
    assert recorded["grid_cells"] == 500  # was refused in a TOML, and not recorded from --grid-cells
    assert set(recorded) == {f.name for f in dataclasses.fields(RunConfig)}
    assert set(RunConfig.RUN_OPTIONS) == set(recorded) - {"filter"}


def test_the_carpark_table_states_the_schedule_the_runs_used():
    from gslam.config import FilterConfig
    from pipelines.bench.carpark import CellResult, markdown_table

    cell = CellResult(8, 10, errors_m=[0.2], online_errors_m=[0.2], filter_ms=[1.0], filter_mean_ms=[1.0])
    cell.end_to_end_ms, cell.rtf, cell.map_points = [1.0], [50.0], [5000]
    text = " ".join(markdown_table([cell], 1, "gslam bench", 1.0).split())
    d = FilterConfig()
    assert f"updated after {d.min_travel_m:g} m or {d.min_turn_rad:g} rad" in text


def test_the_initial_spread_holds_on_an_odometry_log(mit_mcap):
    """`initial_sigma_*` on an odometry log (mit-csail): the particles are moved to the first scan's odometry
    pose at that scan, each keeping its spread (it was dropped there: every particle started at the one
    pose whatever the setting)."""
    import numpy as np

    from gslam.config import FilterConfig
    from gslam.motion import wrap_angle
    from pipelines.run.input_log import InputLog
    from pipelines.run.runner import SlamRunner

    cfg = RunConfig(filter=FilterConfig(initial_sigma_xy_m=0.3, initial_sigma_phi_rad=0.05, loop_closure=False))
    runner = SlamRunner(InputLog(mit_mcap), cfg)
    first = next(runner.steps())
    poses = runner.filter.poses  # the first scan maps an empty map: nothing moves them
    d = poses - first.odom_pose
    d[:, 2] = wrap_angle(d[:, 2])
    assert np.all(np.abs(d.mean(axis=0)) < [0.25, 0.25, 0.04])  # 30 draws: within 4 sd of their mean
    assert 0.15 < d[:, 0].std() < 0.45 and 0.15 < d[:, 1].std() < 0.45 and 0.025 < d[:, 2].std() < 0.075


def test_a_run_end_reads_its_scans_again_by_number(mit_mcap):
    """`InputLog.scans_at`: the scans numbered, the ones between passed over undecoded, as the run read them;
    a number past the input's end is the wrong input, said in one line."""
    import numpy as np
    import pytest

    from pipelines.errors import InputError
    from pipelines.run.input_log import InputLog

    log = InputLog(mit_mcap)
    every = {ev.index: ev for ev in log.events(scans_only=True) if ev.index < 400}
    wanted = [0, 1, 2, 57, 58, 200, 399]
    done = []
    again = list(log.scans_at(wanted, lambda k, total: done.append((k, total))))
    assert [ev.index for ev in again] == wanted
    for ev in again:
        np.testing.assert_array_equal(ev.ranges_m, every[ev.index].ranges_m)
        assert ev.t_s == every[ev.index].t_s and ev.stamp_s == every[ev.index].stamp_s
    assert done[-1] == (400, 400)
    with pytest.raises(InputError, match=f"needs scan {log.scan_count} but the input has {log.scan_count} scans"):
        list(log.scans_at([5, log.scan_count]))
