"""What the commands share: the command line as typed, the output checks, the choices' enums."""

from __future__ import annotations

import sys
from enum import StrEnum
from pathlib import Path

import typer

from gslam.config import FilterConfig
from gslam.vehicle import VEHICLE_PRESETS
from pipelines.methods import NAMES as METHOD_NAMES


def invocation(ctx: typer.Context) -> str:
    """The command line as typed (from sys.argv under the real `gslam` script), else rebuilt from the
    parsed parameters of the current command (e.g. under a test runner)."""
    import shlex

    if Path(sys.argv[0]).name == "gslam":
        return shlex.join(["gslam", *sys.argv[1:]])
    parts = [ctx.command_path]
    for param in ctx.command.params:
        value = ctx.params.get(param.name)
        if value in (None, False) or value == [] or (param.default is not None and value == param.default):
            continue
        if param.param_type_name == "argument":
            parts.append(shlex.quote(str(value)))
            continue
        flag = max(param.opts, key=len)
        values = value if isinstance(value, list | tuple) else [value]
        for v in values:
            parts.append(flag if v is True else f"{flag} {shlex.quote(str(getattr(v, 'value', v)))}")
    return " ".join(parts)


def check_outputs(outputs: dict, inputs: dict) -> None:
    from pipelines.outputs.path_checks import check_outputs as check

    check(outputs, inputs)


class Format(StrEnum):
    auto = "auto"
    sydney_text = "sydney-text"
    sydney_mat = "sydney-mat"
    carmen = "carmen"
    rosbag = "rosbag"


Method = StrEnum("Method", [(m.replace("-", "_"), m) for m in METHOD_NAMES])
Vehicle = StrEnum("Vehicle", [(v, v) for v in VEHICLE_PRESETS])
DEFAULTS = FilterConfig()
"""The filter's defaults, shown in the help."""
