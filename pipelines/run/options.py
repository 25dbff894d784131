"""Build a run's configuration from where the user gave each option (a TOML file, `--set NAME=VALUE`,
flags), checking every value where it was given: a refusal names the flag, or the file and line.

Hostile files are refused in one line, in time linear in their size: a config file must be a regular file
of at most `MAX_TOML_BYTES` (a FIFO, `/dev/zero` or a directory is never read), nested at most `MAX_DEPTH`
levels (deeper TOML or JSON would exhaust Python's recursion), and a refusal quotes at most `QUOTE_CHARS`
characters of any value, name or option as given (never a megabyte list back)."""

from __future__ import annotations

import difflib
import functools
import json
import os
import re
import stat
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from gslam.config import FilterConfig
from mcaplog.tempfiles import file_kind
from pipelines.errors import OptionError
from pipelines.run.runner import RunConfig


@dataclass
class Setting:
    name: str
    value: Any
    source: str
    """Where the value was given, as the user would find it: `--set k=v`, `run.toml:4`, `--particles`."""


MAX_TOML_BYTES = 1 << 20
"""The largest config file read (1 MiB; `gslam config --dump` writes about 12 kB)."""
MAX_DEPTH = 16
"""The deepest nesting of tables and lists accepted (an option's value is at most a list of numbers)."""
QUOTE_CHARS = 80
"""The most characters of a value, a name or an option as given that a refusal quotes."""
LISTED = 5
"""The most unknown option names a refusal lists (it says how many more there are)."""


def shown(text: object, limit: int = QUOTE_CHARS) -> str:
    """`text` as a one-line message may quote it: printable characters only, at most `limit` of them."""
    out = "".join(c if c.isprintable() else "?" for c in str(text)[: limit + 1])
    return out if len(out) <= limit else out[: limit - 3] + "..."


def _clipped(message: str) -> str:
    """A check's message with the value it quotes (after its last ", got ") cut to `QUOTE_CHARS`, and
    the whole kept to one line."""
    head, got, value = message.rpartition(", got ")
    if got:
        message = head + got + shown(value)
    return shown(message, 4 * QUOTE_CHARS)


@functools.lru_cache(maxsize=4)
def _toml_lines(text: str) -> dict[tuple[str | None, str], int]:
    """The 1-based line of the first `key = ...` of each key in each table (None: the top level) of a
    TOML text, found in one pass (looking each key up by a pass of its own is quadratic in the keys)."""
    index: dict[tuple[str | None, str], int] = {}
    current: str | None = None
    head = re.compile(r"^\s*\[\s*([^\]]+?)\s*\]\s*(#.*)?$")
    key = re.compile(r"""^\s*["']?([^"'=]+?)["']?\s*=""")
    for n, line in enumerate(text.splitlines(), start=1):
        table = head.match(line)
        if table:
            current = table.group(1)
            continue
        found = key.match(line)
        if found:
            index.setdefault((current, found.group(1).strip()), n)
    return index


def toml_line(text: str, table: str | None, key: str) -> int | None:
    """The 1-based line of `key = ...` in `[table]` (None: the top level) of a TOML text, if found."""
    return _toml_lines(text).get((table, key))


def where_in_toml(path: Path, text: str, table: str | None, key: str) -> str:
    line = toml_line(text, table, key)
    return f"{path}:{line}" if line else f"{path} ({f'[{table}] ' if table else ''}{shown(key)})"


def _read_config(path: Path, what: str) -> str:
    """The text of the config file at `path`: a regular file of at most MAX_TOML_BYTES in UTF-8. Anything
    else is refused without reading it (a FIFO would block, `/dev/zero` never ends): checked before it
    is opened and again on the open file (it may have been swapped meanwhile)."""

    def refuse_kind(mode: int) -> None:
        if not stat.S_ISREG(mode):
            raise OptionError(f"{path}: {file_kind(mode)}, not a {what} (give a TOML file)")

    def refuse_size(size: int) -> None:
        if size > MAX_TOML_BYTES:
            raise OptionError(f"{path}: {size} bytes, too large for a {what} (at most {MAX_TOML_BYTES} bytes)")

    try:
        st = os.stat(path)
        refuse_kind(st.st_mode)
        refuse_size(st.st_size)
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise OptionError(f"{path}: {what} not found") from None
    except OSError as e:
        raise OptionError(f"{path}: cannot read the {what} ({e.strerror or type(e).__name__})") from None
    with os.fdopen(fd, "rb") as f:
        refuse_kind(os.fstat(f.fileno()).st_mode)
        data = f.read(MAX_TOML_BYTES + 1)
    refuse_size(len(data))
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise OptionError(f"{path}: not a readable {what} (not UTF-8 text)") from None


def _too_deep(value: Any, limit: int = MAX_DEPTH) -> bool:
    """Whether lists and tables nest more than `limit` levels in `value` (walked without recursion)."""
    stack = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict | list | tuple):
            if depth >= limit:
                return True
            stack.extend((v, depth + 1) for v in (item.values() if isinstance(item, dict) else item))
    return False


def load_toml(path: Path, what: str = "config file") -> tuple[dict[str, Any], str]:
    """The parsed TOML and its text; a missing, special, oversized, malformed or too deeply nested file
    is one line naming it."""
    text = _read_config(Path(path), what)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise OptionError(f"{path}: not valid TOML ({shown(e, 2 * QUOTE_CHARS)})") from None
    except RecursionError:
        data = None
    if data is None or _too_deep(data):
        raise OptionError(f"{path}: lists or tables nested more than {MAX_DEPTH} deep; not a {what}")
    return data, text


def parse_set(item: str) -> Setting:
    """`--set NAME=VALUE`: VALUE is read as JSON (numbers, true/false, lists), else kept as text."""
    source = f"--set {shown(item)}"
    if "=" not in item:
        raise OptionError(f"{source}: expected NAME=VALUE")
    name, text = (s.strip() for s in item.split("=", 1))
    too_deep = False
    try:
        value = json.loads(text)  # NaN and Infinity parse to floats and are refused by the check
    except json.JSONDecodeError:
        value = text
    except RecursionError:  # thousands of nested lists
        value, too_deep = None, True
    if too_deep or _too_deep(value):
        raise OptionError(f"{source}: the value nests lists more than {MAX_DEPTH} deep")
    return Setting(name, value, source)


_FILTER_FIELDS = {f.name for f in fields(FilterConfig)}


def _unknown(names: list[str], known: set[str], what: str, where: str, help_: str) -> OptionError:
    """The refusal of unknown option `names` (all of them, in the order given): the first, with the known
    ones it is close to (difflib, for that one name only), then how many more and a few of them."""
    first = names[0]
    near = difflib.get_close_matches(first, sorted(known), n=3) if len(first) <= QUOTE_CHARS else []
    hint = f" (did you mean {', '.join(near)}?)" if near else f" ({help_})"
    more = ""
    if len(names) > 1:
        listed = ", ".join(repr(shown(n, 40)) for n in names[1:LISTED])
        more = f"; {len(names) - 1} more unknown: {listed}{', ...' if len(names) > LISTED else ''}"
    return OptionError(f"{where}: unknown {what} {shown(first)!r}{hint}{more}")


def filter_config(settings: list[Setting], base: FilterConfig | None = None) -> FilterConfig:
    """A FilterConfig from `base` (defaults) and `settings`, each checked alone so that a refusal names
    the place it came from; later settings override earlier ones. Linear in the settings: the names are
    looked up in a set, and only the first unknown one gets suggestions."""
    unknown = [s for s in settings if s.name not in _FILTER_FIELDS]
    if unknown:
        raise _unknown(
            [s.name for s in unknown], _FILTER_FIELDS, "filter option", unknown[0].source, "see docs/CHOICES.md"
        )
    values = (base or FilterConfig()).as_dict()
    for s in settings:
        try:
            FilterConfig(**{s.name: s.value})
        except (ValueError, TypeError) as e:
            raise OptionError(f"{s.source}: {_clipped(str(e))}") from None
        values[s.name] = s.value
    try:
        return FilterConfig.from_dict(values)
    except (ValueError, TypeError) as e:  # a combination of options (each fine alone)
        sources = ", ".join(s.source for s in settings[:LISTED]) or "the defaults"
        if len(settings) > LISTED:
            sources += f" and {len(settings) - LISTED} more"
        raise OptionError(f"{_clipped(str(e))} (options from {sources})") from None


def run_config(
    config_path: Path | None,
    filter_settings: list[Setting],
    run_settings: list[Setting],
) -> RunConfig:
    """The RunConfig of `gslam process`: the TOML file's `[filter]` table and run options, then
    `filter_settings` and `run_settings` (from the command line) over them."""
    file_filter: list[Setting] = []
    file_run: list[Setting] = []
    if config_path is not None:
        data, text = load_toml(config_path)
        table = data.pop("filter", {})
        if not isinstance(table, dict):
            raise OptionError(f"{where_in_toml(config_path, text, None, 'filter')}: 'filter' must be a [filter] table")
        unknown = [k for k in data if k not in RunConfig.RUN_OPTIONS]
        if unknown:
            raise _unknown(
                unknown,
                set(RunConfig.RUN_OPTIONS),
                "run option",
                where_in_toml(config_path, text, None, unknown[0]),
                f"run options: {', '.join(RunConfig.RUN_OPTIONS)}; filter options go in [filter]",
            )
        file_filter = [Setting(k, v, where_in_toml(config_path, text, "filter", k)) for k, v in table.items()]
        file_run = [Setting(k, v, where_in_toml(config_path, text, None, k)) for k, v in data.items()]
    cfg_filter = filter_config(file_filter + filter_settings)
    run_values: dict[str, Any] = {}
    for s in file_run + run_settings:
        try:
            RunConfig(**{s.name: s.value})
            if s.name == "live_url" and s.value is not None:
                from pipelines.run.live_url import parse_live_url

                parse_live_url(s.value)  # the port's range, an IPv6 address in brackets: said here
        except (ValueError, TypeError) as e:
            raise OptionError(f"{s.source}: {_clipped(str(e))}") from None
        run_values[s.name] = s.value
    return RunConfig(filter=cfg_filter, **run_values)
