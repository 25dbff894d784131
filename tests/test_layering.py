"""The package layering: gslam (pure core) <- mcaplog (MCAP format) <- ingest, pipelines; ingest and
pipelines do not import each other's modules (the CLI in pipelines may call ingest)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALLOWED = {
    "gslam": {"gslam"},
    "mcaplog": {"mcaplog"},
    "ingest": {"ingest", "gslam", "mcaplog"},
    "pipelines": {"pipelines", "gslam", "mcaplog", "ingest"},
}


def imported_packages(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
    return found & set(ALLOWED)


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_packages_import_only_below_them(package):
    bad = {
        str(p.relative_to(ROOT)): sorted(imported_packages(p) - ALLOWED[package])
        for p in sorted((ROOT / package).rglob("*.py"))
        if imported_packages(p) - ALLOWED[package]
    }
    assert not bad, bad


def test_only_the_command_line_reaches_into_ingest():
    users = sorted(
        str(p.relative_to(ROOT)) for p in (ROOT / "pipelines").rglob("*.py") if "ingest" in imported_packages(p)
    )
    allowed = {"cli/app.py", "cli/errors.py", "demo/run.py", "bench/sweep.py", "bench/carpark.py", "bench/suites.py"}
    assert set(users) <= {f"pipelines/{name}" for name in allowed}, users
