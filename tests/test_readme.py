"""The README's code blocks run as written, in a fresh directory laid out as a clone beside `../shared`.

Every line of every ```bash block is run, in order, by bash, except three kinds that cannot run here,
each checked instead: the install line (the environment running this test is that install: only its
last command, `gslam demo`, runs), the test command (this is it) and the viewer (`rerun FILE.rrd`: the
file must be a recording). `my_run.bag`, the README's own bag, is written first: the first scans of
mit-csail as a ROS 1 bag with odometry and the laser's mount, as a robot records them.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import CARPARK, DATASETS, MIT, ROOT, require

README = ROOT / "README.md"
INSTALL = "python3 -m venv .venv && . .venv/bin/activate && pip install -e '.[dev]' && "
TESTS = "python -m pytest -q"


def bash_lines(text: str) -> list[str]:
    """The command lines of the README's ```bash blocks, in order (continuations joined, comments kept)."""
    lines: list[str] = []
    for block in re.findall(r"^```bash\n(.*?)^```", text, flags=re.S | re.M):
        pending = ""
        for line in block.splitlines():
            if line.rstrip().endswith("\\"):
                pending += line.rstrip()[:-1] + " "
                continue
            line = (pending + line).strip()
            pending = ""
            if line and not line.startswith("#"):
                lines.append(line)
    return lines


def test_the_readme_stays_a_short_guide():
    text = README.read_text()
    assert len(text.splitlines()) <= 150
    assert not re.search(r"\b20\d\d-\d\d-\d\d \d\d:\d\d\b", text), "a diary time in the README"
    lines = bash_lines(text)
    assert lines[0].startswith(INSTALL) and TESTS in lines, lines[:2]
    assert any(line.startswith("rerun --web-viewer ") for line in lines), "no headless way to open a recording"


def test_the_readmes_code_blocks_run_as_written(tmp_path):
    require(CARPARK)
    require(MIT)
    clone = tmp_path / "clone"
    (clone / "recordings").mkdir(parents=True)
    (tmp_path / "shared").mkdir()
    (tmp_path / "shared" / "datasets").symlink_to(DATASETS.resolve())
    _write_bag(clone / "my_run.bag")
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    ran = []
    for line in bash_lines(README.read_text()):
        if line.startswith(INSTALL):
            line = line.removeprefix(INSTALL)  # installed already: this test runs in that environment
        if line == TESTS:
            continue
        if line.startswith("rerun "):
            recording = clone / shlex.split(line)[-1]
            assert recording.suffix == ".rrd" and recording.stat().st_size > 0, line
            continue
        done = subprocess.run(["bash", "-c", line], cwd=clone, env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, f"{line}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
        assert "Traceback" not in done.stderr, done.stderr
        ran.append(line)
    assert len(ran) >= 10, ran
    for written in ("recordings/cp.png", "recordings/my_map.yaml", "recordings/mit_loc.tum"):
        assert (clone / written).stat().st_size > 0, written
    # what git would see after the quick start: nothing but ignored files
    outputs = [p.relative_to(clone).as_posix() for p in clone.rglob("*") if p.is_file() and p.name != "my_run.bag"]
    for output in outputs:
        status = subprocess.run(["git", "-C", str(ROOT), "check-ignore", "--no-index", "-q", output])
        if status.returncode == 128:
            pytest.skip("git could not be asked about .gitignore")
        assert status.returncode == 0, f"{output}, written by the README's commands, is not ignored by git"


def _write_bag(path: Path) -> None:
    """The README's `my_run.bag`: mit-csail's first 400 scans as a ROS 1 bag (odometry on /odom, the
    laser's mount in /tf_static)."""
    from bagtools import bag_from_log

    from ingest import read_log

    bag_from_log(read_log(MIT), path, "ros1", 400, mount=(0.1, 0.0, 0.0))
