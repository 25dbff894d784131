"""Temporary files beside an output: `.NAME.PID.tmp`, written first and renamed to NAME when complete.

A process killed with SIGKILL (or a machine that loses power) leaves its temporary behind; the next
run that writes NAME removes every `.NAME.<pid>.tmp` whose process is no longer alive
(`temporary_for`). `describe_temporary` says what such a file is, for `gslam info`.
No dependency on the rest of the project: ingest, the pipelines and the writers all use it.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

_TEMP = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.tmp$")


def pid_alive(pid: int) -> bool:
    """Whether a process with this id exists (on this machine)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return True
    return True


def remove_stale_temporaries(path: Path) -> list[Path]:
    """Remove the temporaries of `path` left by processes that are no longer running; returns them."""
    path = Path(path)
    removed = []
    try:
        candidates = list(path.parent.glob(f".{glob_escape(path.name)}.*.tmp"))
    except OSError:
        return removed
    for tmp in candidates:
        m = _TEMP.match(tmp.name)
        if m is None or m["name"] != path.name:
            continue
        pid = int(m["pid"])
        if pid != os.getpid() and not pid_alive(pid):
            try:
                tmp.unlink()
                removed.append(tmp)
            except OSError:
                pass
    return removed


def glob_escape(name: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", name)


def temporary_for(path: Path) -> Path:
    """The temporary to write before renaming to `path` (this process's), after removing stale ones."""
    path = Path(path)
    remove_stale_temporaries(path)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def write_atomic(path: Path, content: str | bytes) -> Path:
    """Write `content` to `path` through its temporary (no half-written file at `path`, ever)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_for(path)
    try:
        if isinstance(content, bytes):
            tmp.write_bytes(content)
        else:
            tmp.write_text(content)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


@dataclass
class TemporaryInfo:
    final: Path
    pid: int
    alive: bool

    def describe(self, path: Path) -> str:
        state = (
            f"process {self.pid} is still writing it"
            if self.alive
            else f"process {self.pid} is no longer running: the run was killed before it finished "
            f"(the next run writing {self.final.name} removes it)"
        )
        return f"{path}: an unfinished temporary file of gslam for {self.final}; {state}"


def describe_temporary(path: Path) -> TemporaryInfo | None:
    """What a `.NAME.PID.tmp` file is, or None when `path` is not named like one."""
    path = Path(path)
    m = _TEMP.match(path.name)
    if m is None:
        return None
    pid = int(m["pid"])
    return TemporaryInfo(path.with_name(m["name"]), pid, pid_alive(pid))


def final_name(filename: str) -> str:
    """The output a temporary stands for (`dir/.x.mcap.123.tmp` -> `dir/x.mcap`); other names unchanged."""
    p = Path(filename)
    m = _TEMP.match(p.name)
    return str(p.with_name(m["name"])) if m else filename
