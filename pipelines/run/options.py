"""Build a run's configuration from where the user gave each option (a TOML file, `--set NAME=VALUE`,
flags), checking every value where it was given: a refusal names the flag, or the file and line."""

from __future__ import annotations

import difflib
import json
import re
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from gslam.config import FilterConfig
from pipelines.errors import OptionError
from pipelines.run.runner import RunConfig


@dataclass
class Setting:
    name: str
    value: Any
    source: str
    """Where the value was given, as the user would find it: `--set k=v`, `run.toml:4`, `--particles`."""


def toml_line(text: str, table: str | None, key: str) -> int | None:
    """The 1-based line of `key = ...` in `[table]` (None: the top level) of a TOML text, if found."""
    current: str | None = None
    pattern = re.compile(rf"^\s*[\"']?{re.escape(key)}[\"']?\s*=")
    for n, line in enumerate(text.splitlines(), start=1):
        head = re.match(r"^\s*\[\s*([^\]]+?)\s*\]\s*(#.*)?$", line)
        if head:
            current = head.group(1)
        elif current == table and pattern.match(line):
            return n
    return None


def where_in_toml(path: Path, text: str, table: str | None, key: str) -> str:
    line = toml_line(text, table, key)
    return f"{path}:{line}" if line else f"{path} ({f'[{table}] ' if table else ''}{key})"


def load_toml(path: Path, what: str = "config file") -> tuple[dict[str, Any], str]:
    """The parsed TOML and its text; a missing or malformed file is one line naming it."""
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        raise OptionError(f"{path}: {what} not found") from None
    except (IsADirectoryError, UnicodeDecodeError) as e:
        raise OptionError(f"{path}: not a readable {what} ({type(e).__name__})") from None
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as e:
        raise OptionError(f"{path}: not valid TOML ({e})") from None


def parse_set(item: str) -> Setting:
    """`--set NAME=VALUE`: VALUE is read as JSON (numbers, true/false, lists), else kept as text."""
    if "=" not in item:
        raise OptionError(f"--set {item}: expected NAME=VALUE")
    name, text = (s.strip() for s in item.split("=", 1))
    try:
        value = json.loads(text)  # NaN and Infinity parse to floats and are refused by the check
    except json.JSONDecodeError:
        value = text
    return Setting(name, value, f"--set {item}")


_FILTER_FIELDS = {f.name for f in fields(FilterConfig)}


def filter_config(settings: list[Setting], base: FilterConfig | None = None) -> FilterConfig:
    """A FilterConfig from `base` (defaults) and `settings`, each checked alone so that a refusal names
    the place it came from; later settings override earlier ones."""
    values = (base or FilterConfig()).as_dict()
    for s in settings:
        if s.name not in _FILTER_FIELDS:
            near = difflib.get_close_matches(s.name, sorted(_FILTER_FIELDS), n=3)
            hint = f" (did you mean {', '.join(near)}?)" if near else " (see docs/CHOICES.md)"
            raise OptionError(f"{s.source}: unknown filter option {s.name!r}{hint}")
        try:
            FilterConfig(**{s.name: s.value})
        except (ValueError, TypeError) as e:
            raise OptionError(f"{s.source}: {e}") from None
        values[s.name] = s.value
    try:
        return FilterConfig.from_dict(values)
    except (ValueError, TypeError) as e:  # a combination of options (each fine alone)
        sources = ", ".join(s.source for s in settings) or "the defaults"
        raise OptionError(f"{e} (options from {sources})") from None


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
        file_filter = [Setting(k, v, where_in_toml(config_path, text, "filter", k)) for k, v in table.items()]
        for k, v in data.items():
            where = where_in_toml(config_path, text, None, k)
            if k not in RunConfig.RUN_OPTIONS:
                raise OptionError(
                    f"{where}: unknown run option {k!r}; run options: {', '.join(RunConfig.RUN_OPTIONS)}, "
                    f"filter options go in [filter]"
                )
            file_run.append(Setting(k, v, where))
    cfg_filter = filter_config(file_filter + filter_settings)
    run_values: dict[str, Any] = {}
    for s in file_run + run_settings:
        try:
            RunConfig(**{s.name: s.value})
        except (ValueError, TypeError) as e:
            raise OptionError(f"{s.source}: {e}") from None
        run_values[s.name] = s.value
    return RunConfig(filter=cfg_filter, **run_values)
