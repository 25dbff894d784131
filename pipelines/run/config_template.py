"""`gslam config --dump`: every option of `gslam process` with its default and one line of help, as a
TOML file that `--config` reads back (run options at the top, filter options in `[filter]`).

The help is the first sentence of each field's docstring (`gslam.config.FilterConfig`,
`pipelines.run.runner.RunConfig`), read from the source, so the template cannot fall behind the code.
Options whose default is None (no value: each says what it then does) are written commented out: TOML has
no null.
"""

from __future__ import annotations

import ast
import inspect
import json
import math
import os
import re
import stat
import textwrap
from dataclasses import fields
from pathlib import Path
from typing import Any

from gslam import __version__
from gslam.config import FilterConfig
from pipelines.run.runner import RunConfig


def field_docs(cls: type) -> dict[str, str]:
    """The docstring written under each field of a dataclass (empty when there is none)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body
    docs: dict[str, str] = {}
    for node, after in zip(body, body[1:] + [None], strict=True):
        if not isinstance(node, ast.AnnAssign) or not isinstance(node.target, ast.Name):
            continue
        is_doc = isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
        docs[node.target.id] = after.value.value if is_doc and isinstance(after.value.value, str) else ""
    return docs


def one_line(doc: str, width: int = 110) -> str:
    """The first sentence of a docstring, on one line of at most `width` characters."""
    text = " ".join(doc.split())
    m = re.search(r"\.(\s+[A-Z0-9(\"]|$)", text)  # a full stop ending a sentence (not "e.g. a", "1.5")
    first = text[: m.start() + 1] if m else text
    return first if len(first) <= width else first[: width - 3].rstrip() + "..."


def toml_value(value: Any) -> str:
    """`value` as TOML (strings, booleans, integers, floats with inf and nan, arrays)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {value!r}")


def _lines(obj: Any, docs: dict[str, str], skip: tuple[str, ...] = ()) -> list[str]:
    out: list[str] = []
    for f in fields(obj):
        if f.name in skip:
            continue
        value = getattr(obj, f.name)
        help_line = one_line(docs.get(f.name, ""))
        if help_line:
            out.append(f"# {help_line}")
        if value is None:
            out.append(f"# {f.name} =   (no value by default: the line above says what that means)")
        else:
            out.append(f"{f.name} = {toml_value(value)}")
        out.append("")
    return out


TEMPLATE_FIRST_LINE = re.compile(rb"# gslam [^\s:]+: every option of `gslam process`")
"""The first line of every template `config_toml` wrote (any version): how `gslam config --dump -o FILE`
knows an existing FILE is one it wrote, the only kind it replaces."""


def is_template(path: Path) -> bool:
    """Whether `path` is a regular file whose first line is a template's (`TEMPLATE_FIRST_LINE`). Reads
    at most its first 200 bytes, and nothing of anything but a regular file (a FIFO would block)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return False
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return False
        return TEMPLATE_FIRST_LINE.match(os.read(fd, 200)) is not None
    except OSError:
        return False
    finally:
        os.close(fd)


def config_toml() -> str:
    """The template: the defaults of this version, every option, one line of help each."""
    run = RunConfig()
    head = [
        f"# gslam {__version__}: every option of `gslam process`, at its default.",
        "# Read back with `gslam process IN OUT --config FILE`; flags and --set given on the command line",
        "# override the file. docs/CHOICES.md gives the measured effect of the filter's options.",
        "",
        "# ---- run options ----",
        "",
    ]
    body = _lines(run, field_docs(RunConfig), skip=("filter",))
    filt = ["[filter]", ""] + _lines(run.filter, field_docs(FilterConfig))
    return "\n".join(head + body + filt).rstrip() + "\n"
