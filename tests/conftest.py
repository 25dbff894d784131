"""Shared fixtures: the real datasets in ../shared/datasets (skipped with a reason when absent, except
under CI=true where a missing dataset fails the run), and ingested MCAPs cached per session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATASETS = Path(os.environ.get("GSLAM_DATASETS", ROOT.parent / "shared" / "datasets"))
CARPARK = DATASETS / "carpark"
VICTORIA = DATASETS / "victoria_park"
MIT = DATASETS / "freiburg" / "mit-csail.clf.gz"
INTEL = DATASETS / "freiburg" / "intel.clf.gz"
FR079 = DATASETS / "freiburg" / "fr079.clf.gz"


def require(path: Path) -> Path:
    """The dataset path, or skip with a reason (fail under CI, where the data must be there)."""
    if not path.exists():
        message = f"dataset not found: {path} (the shared datasets live in ../shared/datasets)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(message + "; under CI the data must be present")
        pytest.skip(message)
    return path


@pytest.fixture(scope="session")
def carpark_mcap(tmp_path_factory) -> Path:
    from ingest import ingest

    out = tmp_path_factory.mktemp("carpark") / "carpark.mcap"
    ingest(require(CARPARK), out)
    return out


@pytest.fixture(scope="session")
def fr079_mcap(tmp_path_factory) -> Path:
    from ingest import ingest

    out = tmp_path_factory.mktemp("fr079") / "fr079.mcap"
    ingest(require(FR079), out)
    return out


@pytest.fixture(scope="session")
def mit_mcap(tmp_path_factory) -> Path:
    from ingest import ingest

    out = tmp_path_factory.mktemp("mit") / "mit.mcap"
    ingest(require(MIT), out)
    return out


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> dict[str, Path]:
    """A tiny simulated Sydney log's input MCAP and a result of it (one per test module: tests write
    beside them)."""
    from test_reliability import write_log

    from ingest import ingest
    from pipelines.process import process
    from pipelines.run.runner import RunConfig

    d = tmp_path_factory.mktemp("small")
    ingest(write_log(d / "log"), d / "in.mcap")
    process(d / "in.mcap", d / "r.mcap", None, RunConfig())
    return {"dir": d, "in": d / "in.mcap", "result": d / "r.mcap"}


def pytest_collection_modifyitems(config, items):
    """Tests marked `fuzz` (the long profile) run only when `-m` selects them."""
    if "fuzz" in (config.getoption("markexpr") or ""):
        return
    skip = pytest.mark.skip(reason="the 10 000-case fuzz profile runs with `python -m pytest -m fuzz`")
    for item in items:
        if "fuzz" in item.keywords:
            item.add_marker(skip)


def pytest_terminal_summary(terminalreporter):
    """Counts of the fuzz suite (cases, refused with a clear error, read), when it ran."""
    import sys

    fuzz = sys.modules.get("test_fuzz") or sys.modules.get("tests.test_fuzz")
    if fuzz is None or not fuzz.COUNTS:
        return
    terminalreporter.section("fuzz")
    for name, c in fuzz.COUNTS.items():
        terminalreporter.write_line(f"{name}: {c['cases']} cases, {c['refused']} refused, {c['read']} read")
    total = sum(c["cases"] for c in fuzz.COUNTS.values())
    terminalreporter.write_line(f"total: {total} cases")
