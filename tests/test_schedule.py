"""Start-up and scheduling of the compiled kernels (gslam.workqueue, pipelines.run.startup)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from gslam.workqueue import next_index


def test_next_index_hands_out_each_index_once_across_threads():
    from numba import njit, prange

    @njit(parallel=True)
    def take_all(n, workers):
        taken = np.zeros(n, dtype=np.int64)
        counter = np.zeros(1, dtype=np.int64)
        for _w in prange(workers):
            while True:
                i = next_index(counter)
                if i >= n:
                    break
                taken[i] += 1
        return taken

    taken = take_all(10_000, 4)
    assert (taken == 1).all()  # taken by one worker, whatever the number of workers and threads
    assert (take_all(7, 1) == 1).all()


def test_the_kernels_run_without_numbas_blas_probe_and_scipy_linalg_still_imports():
    code = """
import sys
import numpy as np
from pipelines.run.startup import skip_blas_probe
skip_blas_probe()
from gslam.motion import integrate_ackermann
from gslam.vehicle import VEHICLE_PRESETS
poses = integrate_ackermann(np.zeros((3, 3)), np.array([[0.0, 1.0, 0.1]]), 1.0, 0.0, VEHICLE_PRESETS["carpark"], None,
                            0.0, 0.0, 0.0)
assert poses[0, 0] > 0.9, poses
assert "scipy.linalg" not in sys.modules, "the probe was not skipped"
import scipy.linalg.cython_blas  # noqa: F401  (imports as usual afterwards)
print("ok")
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_the_gslam_script_freezes_the_heap_on_exit_and_keeps_exit_codes_output_and_atexit(tmp_path):
    code = """
import atexit, gc, sys
from pipelines import cli
atexit.register(lambda: print("atexit ran, frozen:", gc.get_freeze_count() > 0, flush=True))
sys.argv = ["gslam", *sys.argv[1:]]
cli.run()
"""
    ok = subprocess.run([sys.executable, "-c", code, "--version"], capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.splitlines()[0].startswith("gslam "), ok.stdout
    assert "atexit ran, frozen: True" in ok.stdout
    missing = tmp_path / "missing.mcap"
    bad = subprocess.run(
        [sys.executable, "-c", code, "process", str(missing), str(tmp_path / "out.mcap")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert bad.returncode != 0
    assert "atexit ran, frozen: True" in bad.stdout
    assert "Traceback" not in bad.stderr and "missing.mcap" in bad.stderr, bad.stderr


def test_the_pipelines_start_numpy_without_openblas_threads_and_keep_a_users_setting():
    code = """
import os, sys
import pipelines.cli.app  # noqa: F401  (imports numpy)
tasks = len(os.listdir("/proc/self/task")) if sys.platform == "linux" else 1
print(os.environ["OPENBLAS_NUM_THREADS"], tasks)
"""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["1", "1"], out.stdout  # one thread: the interpreter's own
    env["OPENBLAS_NUM_THREADS"] = "2"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert out.stdout.split()[0] == "2", out.stdout
