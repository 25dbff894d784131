"""Check a command's output paths before any work: none may be (or lie inside) one of its inputs, be
anything but a regular file when it exists (a directory, a device, a FIFO, a socket or a symlink: every
output is a temporary renamed into place, which would put a regular file where `/dev/null` was),
repeat another output, or sit where nothing can be written. Each refusal is one line naming the option
and the path (and the input it would destroy)."""

from __future__ import annotations

import errno
import os
from pathlib import Path

from mcaplog.tempfiles import create_temporary, describe_non_regular
from pipelines.errors import OutputError

Labelled = dict[str, Path | None]


def _same(a: Path, b: Path) -> bool:
    """Whether two paths name the same file: equal once resolved (symlinks followed), or hard links."""
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _inside(path: Path, directory: Path) -> bool:
    try:
        path.resolve().relative_to(directory.resolve())
    except ValueError:
        return False
    return True


def _writable_dir(label: str, path: Path) -> None:
    """Refuse `path` when its directory cannot hold a new file (read-only, no permission, not a dir)."""
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"{label} {path}: cannot create it, {parent} is not a directory")
    try:
        fd, probe = create_temporary(parent / path.name)
    except OSError as e:
        why = os.strerror(e.errno) if e.errno else str(e)
        if e.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
            why += f": choose a writable directory for {label}"
        raise OutputError(f"{label} {path}: cannot write in {parent} ({why})") from None
    os.close(fd)
    probe.unlink(missing_ok=True)


def _resolvable(label: str, path: Path) -> None:
    """Refuse a path that cannot be resolved (a symlink loop, a name too long)."""
    try:
        path.resolve()
    except (OSError, RuntimeError) as e:  # RuntimeError: Python's "Symlink loop from ..."
        why = e.strerror if isinstance(e, OSError) and e.strerror else "a symlink loop"
        raise OutputError(f"{label} {path}: cannot be resolved ({why}); give another path") from None


def _regular_or_absent(label: str, path: Path) -> None:
    """Refuse an output path that exists and is not a regular file, without opening it: a directory, a
    device (`/dev/null`), a FIFO, a socket or a symlink (`/dev/stdout` is one, to `/proc/self/fd/1`) is
    never replaced (the rename of the output's temporary would put a regular file in its place)."""
    what = describe_non_regular(path)
    if what is None:
        return
    if what == "a directory":
        raise OutputError(f"{label} {path} is a directory; give the path of a file to write")
    raise OutputError(f"{label} {path} is {what}: an output replaces only a regular file; give the path of one")


def check_outputs(outputs: Labelled, inputs: Labelled) -> None:
    """`outputs` and `inputs` map a label as the user typed it (`-o`, `--rrd`, `INPUT`) to a path
    (None: not given). Raises OutputError for the first output that cannot be written safely."""
    given_in = {k: Path(v) for k, v in inputs.items() if v is not None}
    for label, src in given_in.items():
        _resolvable(label, src)
    seen: dict[str, Path] = {}
    for label, out in outputs.items():
        if out is None:
            continue
        out = Path(out)
        _resolvable(label, out)
        for in_label, src in given_in.items():
            if src.exists() and _same(out, src):
                raise OutputError(
                    f"{label} {out} is the input {in_label} {src}: it would be overwritten; choose another output path"
                )
            if src.is_dir() and _inside(out, src):
                raise OutputError(
                    f"{label} {out} is inside the input directory {in_label} {src}: "
                    f"write the output elsewhere so the input stays untouched"
                )
        for other_label, other in seen.items():
            if _same(out, other):
                raise OutputError(f"{label} {out} is the same file as {other_label} {other}; give each output its own")
        _regular_or_absent(label, out)  # compared with the inputs first: "is the input" says more
        _writable_dir(label, out)
        seen[label] = out
