"""Temporary files beside an output: `.NAME.PID-START-RANDOM.tmp`, written first and renamed to NAME when
complete.

A temporary is created with `O_CREAT | O_EXCL | O_NOFOLLOW` under a name no other process can guess
(`RANDOM`: 48 random bits), so a file or symlink planted beside an output is never opened or written
through, whoever runs gslam. The name records the writing process's id and its start time (`START`, in
clock ticks since boot, from `/proc`), so a later run can prove a temporary is a dead process's.

A process killed with SIGKILL (or a machine that loses power) leaves its temporary behind; the next run
that writes NAME removes the temporaries of NAME that it can prove are stale (`remove_stale_temporaries`):
a regular file (not a symlink), owned by this user, whose recorded process is gone or is another process
now (same id, other start time). Anything else beside the output is left alone. `describe_temporary`
says what such a file is, for `gslam info`.

Only a regular file (or nothing) is ever replaced: renaming a temporary over a device, a FIFO, a socket, a
directory or a symlink (`-o /dev/stdout`, a link to `/proc/self/fd/1`) would put a regular file where it
was, which as root replaces `/dev/null` or `/dev/stdout` for every program. `create_temporary` and
`replace` refuse such a path (`NotRegularFileError`), the last guard behind the commands' own check of
their outputs.

A signal can land between the creation of a temporary and the moment its writer holds its name (inside
`create_temporary`, or before the caller has stored what it returned); no writer then knows to drop it.
So every temporary is also recorded here from before it exists until it is renamed into place
(`replace`), and the command line's exit removes the ones of this process still present
(`remove_own_temporaries`).
No dependency on the rest of the project: ingest, the pipelines and the writers all use it.
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import stat
from dataclasses import dataclass
from pathlib import Path

_TEMP = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)-(?P<start>\d+)-(?P<rand>[0-9a-f]{12})\.tmp$")
_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


def process_start(pid: int) -> int | None:
    """The start time of process `pid` (clock ticks since boot, `/proc/PID/stat` field 22), None when it
    does not exist or cannot be read (no /proc)."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_bytes()
    except OSError:
        return None
    try:  # the command name (field 2) is in parentheses and may hold spaces: count from the last ")"
        return int(raw[raw.rindex(b")") + 2 :].split()[19])
    except (ValueError, IndexError):
        return None


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


def _writer_alive(pid: int, start: int) -> bool:
    """Whether the process that created a temporary (id and recorded start time) still runs."""
    if not pid_alive(pid):
        return False
    now = process_start(pid)
    return now is None or start == 0 or now == start  # no /proc: cannot tell a reused id, assume alive


_OWN_PID, _OWN_START = os.getpid(), process_start(os.getpid()) or 0


def _own_start() -> int:
    """This process's start time (re-read after a fork: a child has its own)."""
    global _OWN_START, _OWN_PID
    if _OWN_PID != os.getpid():
        _OWN_PID, _OWN_START = os.getpid(), process_start(os.getpid()) or 0
    return _OWN_START


def remove_stale_temporaries(path: Path) -> list[Path]:
    """Remove the temporaries of `path` that are provably stale: regular files of this user whose writing
    process is gone; returns them."""
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
        try:
            st = os.lstat(tmp)
        except OSError:
            continue
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.geteuid():
            continue
        pid, start = int(m["pid"]), int(m["start"])
        if pid == os.getpid() or _writer_alive(pid, start):
            continue
        try:
            tmp.unlink()
            removed.append(tmp)
        except OSError:
            pass
    return removed


class NotRegularFileError(OSError):
    """An output path exists and is not a regular file (a device, FIFO, socket or directory, or a symlink
    to one): it is never replaced. An OSError naming the path, so the CLI prints it as `path: reason`."""


def file_kind(mode: int) -> str:
    """What a file of this `st_mode` is, in words ("a FIFO", "a character device", ...)."""
    kinds = (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISREG, "a regular file"),
    )
    return next((word for test, word in kinds if test(mode)), "not a regular file")


def describe_non_regular(path: Path) -> str | None:
    """What stands at `path` when it exists and is not a regular file, in words ("a FIFO (named pipe)",
    "a symlink (to /dev/null, a character device)"); None when nothing is there or a regular file is. A
    symlink counts as not a regular file whatever it points to: renaming onto it replaces the link, and
    `/dev/stdout` is one (to `/proc/self/fd/1`, a regular file when the output is redirected to one)."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    if stat.S_ISREG(st.st_mode):
        return None
    if not stat.S_ISLNK(st.st_mode):
        return file_kind(st.st_mode)
    target = os.path.realpath(path)
    try:
        to = file_kind(os.stat(path).st_mode)
    except OSError:
        to = "which does not exist"
    return f"a symlink (to {target}, {to})"


def check_replaceable(path: Path) -> None:
    """Raise NotRegularFileError when `path` exists and is not a regular file (a directory, device, FIFO,
    socket or symlink): only a regular file, or nothing, may be replaced by an output. Never opens it."""
    what = describe_non_regular(path)
    if what is not None:
        raise NotRegularFileError(
            errno.EEXIST, f"exists and is {what}: an output replaces only a regular file", str(path)
        )


_OWN: dict[Path, int] = {}
"""This process's temporaries not yet renamed into place, each with the id of the process that made it
(a forked child inherits the record but not the files' ownership)."""


def replace(tmp: Path, path: Path) -> None:
    """Move the finished temporary `tmp` to `path` (`os.replace`), unless `path` has become something
    other than a regular file meanwhile (NotRegularFileError; the temporary is left to the caller)."""
    check_replaceable(path)
    os.replace(tmp, path)
    _OWN.pop(Path(tmp), None)


def remove_own_temporaries() -> list[Path]:
    """Remove the temporaries this process created and did not rename into place (a writer that a signal
    stopped before it knew its temporary), and return those that were still there. For the command line's
    exit: by then every output was finished or aborted, so any left is an orphan."""
    removed = []
    pid = os.getpid()
    for tmp, owner in list(_OWN.items()):
        if owner != pid:
            continue
        _OWN.pop(tmp, None)
        try:
            tmp.unlink()
            removed.append(tmp)
        except FileNotFoundError:
            pass  # its writer removed it
        except OSError:
            pass  # cannot: the next run writing the same output removes it as stale
    return removed


def glob_escape(name: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", name)


def create_temporary(path: Path) -> tuple[int, Path]:
    """Create this process's new temporary for `path` (after removing stale ones): an open descriptor
    for writing and its path. Never opens an existing file or follows a symlink. NotRegularFileError when
    `path` exists and is not a regular file: nothing could be renamed onto it."""
    path = Path(path)
    check_replaceable(path)
    remove_stale_temporaries(path)
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{os.getpid()}-{_own_start()}-{secrets.token_hex(6)}.tmp")
        _OWN[tmp] = os.getpid()  # before it exists: a signal from here on cannot orphan it
        try:
            return os.open(tmp, _FLAGS, 0o666), tmp
        except FileExistsError:
            _OWN.pop(tmp, None)
            continue
    raise FileExistsError(errno.EEXIST, "cannot create a temporary file", str(path))


def temporary_for(path: Path) -> Path:
    """Create this process's new (empty) temporary for `path` and return its path, for a writer that opens
    it by name; `create_temporary` gives the descriptor instead."""
    fd, tmp = create_temporary(path)
    os.close(fd)
    return tmp


def write_atomic(path: Path, content: str | bytes) -> Path:
    """Write `content` to `path` through its temporary (no half-written file at `path`, ever). A failed
    write (disk full, I/O error) removes the temporary and raises OSError naming `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = content if isinstance(content, bytes) else content.encode()
    fd, tmp = create_temporary(path)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        replace(tmp, path)
    except NotRegularFileError:
        tmp.unlink(missing_ok=True)
        raise
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise OSError(e.errno, e.strerror, str(path)) from None
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
    """What a `.NAME.PID-START-RANDOM.tmp` file is, or None when `path` is not named like one."""
    path = Path(path)
    m = _TEMP.match(path.name)
    if m is None:
        return None
    pid = int(m["pid"])
    return TemporaryInfo(path.with_name(m["name"]), pid, _writer_alive(pid, int(m["start"])))


def final_name(filename: str) -> str:
    """The output a temporary stands for (`dir/.x.mcap.123-456-0a1b2c3d4e5f.tmp` -> `dir/x.mcap`); other
    names unchanged."""
    p = Path(filename)
    m = _TEMP.match(p.name)
    return str(p.with_name(m["name"])) if m else filename
