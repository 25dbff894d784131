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
    """The command line, the demo and the benchmarks ingest logs; the run and its outputs read MCAP only."""
    users = {
        p.relative_to(ROOT / "pipelines").parts[0]
        for p in (ROOT / "pipelines").rglob("*.py")
        if "ingest" in imported_packages(p)
    }
    assert users <= {"cli", "demo", "bench"}, users


# Inside pipelines, each room imports only the rooms below it (the command line at the top).
PIPELINE_ROOMS = ["cli", "bench", "demo", "process", "localise", "outputs", "evaluation", "run", "methods", "errors"]


def _runtime_imports(path: Path) -> set[str]:
    """The pipelines rooms a module imports at run time (imports under `if TYPE_CHECKING:` left out)."""
    tree = ast.parse(path.read_text())
    typing_only = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            typing_only |= {id(n) for n in ast.walk(node)}
    found = set()
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        found |= {n.split(".")[1] for n in names if n.startswith("pipelines.")}
    return found


def test_pipeline_rooms_import_only_the_rooms_below_them():
    rank = {room: i for i, room in enumerate(PIPELINE_ROOMS)}
    upward = {}
    for p in sorted((ROOT / "pipelines").rglob("*.py")):
        room = p.relative_to(ROOT / "pipelines").parts[0].removesuffix(".py")
        if room == "__init__":
            continue
        assert room in rank, f"{p}: a room of pipelines/ not in PIPELINE_ROOMS"
        bad = sorted(r for r in _runtime_imports(p) if r != room and rank[r] < rank[room])
        if bad:
            upward[str(p.relative_to(ROOT))] = bad
    assert not upward, upward


def _module_imports(path: Path) -> set[str]:
    """The pipelines modules a module imports, at run time or for typing alone (any import is an edge)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module)
            found |= {f"{node.module}.{a.name}" for a in node.names}
    return {n for n in found if n.startswith("pipelines.")}


def test_no_two_pipelines_modules_import_each_other_even_for_typing():
    """No import circle in pipelines/ (a registry that imports its user's types only to name them is one)."""
    modules = {
        ".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__"): p
        for p in (ROOT / "pipelines").rglob("*.py")
    }
    graph = {name: {m for m in _module_imports(p) if m in modules and m != name} for name, p in modules.items()}
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt) :] + [nxt] if nxt in stack else [node, nxt])
            elif nxt not in state:
                visit(nxt, [*stack, nxt])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    # a package's __init__ importing its own submodules (and they the package) is not a circle of modules
    cycles = [c for c in cycles if not all(a.startswith(b) or b.startswith(a) for a, b in zip(c, c[1:], strict=False))]
    assert not cycles, cycles
