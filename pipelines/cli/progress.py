"""Progress of long commands: a rich bar on a terminal; off a terminal (a pipe, a log file, CI) one
plain line to stderr every few seconds, so a run is never silent for long."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import typer

Report = Callable[..., None]
"""`report(done, total, *details)`: `done` of `total` units finished."""

EVERY_S = 5.0
"""Seconds between two plain progress lines (environment: GSLAM_PROGRESS_EVERY_S)."""


class PlainProgress:
    """One line every `every_s` seconds and one at the end: `label: done/total unit (pct), rate, elapsed`."""

    def __init__(self, label: str, unit: str, every_s: float | None = None, write: Callable[[str], None] | None = None):
        self.label = label
        self.unit = unit
        self.every_s = float(os.environ.get("GSLAM_PROGRESS_EVERY_S", EVERY_S)) if every_s is None else every_s
        self.write = write or (lambda line: print(line, file=sys.stderr, flush=True))
        self.t0 = time.monotonic()
        self.last = self.t0
        self.lines = 0

    def __call__(self, done: int, total: int | None, *details) -> None:
        """A line when `every_s` has passed since the last; the last one (done == total) only after
        others, so a short run stays quiet."""
        now = time.monotonic()
        due = now - self.last >= self.every_s
        if not (due or (done == total and self.lines)):
            return
        self.last = now
        self.lines += 1
        elapsed = now - self.t0
        of = f"/{total}" if total else ""
        pct = f" ({100 * done / total:.0f}%)" if total else ""
        rate = f", {done / elapsed:.0f} {self.unit}/s" if elapsed > 0 else ""
        self.write(f"{self.label}: {done}{of} {self.unit}{pct}{rate}, {elapsed:.0f} s")


def on_terminal() -> bool:
    return sys.stderr.isatty() or bool(os.environ.get("GSLAM_PROGRESS"))


def progress_bar():
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        transient=False,
    )


@contextmanager
def reporting(label: str, unit: str = "scans") -> Iterator[tuple[Report, Callable[[str], None]]]:
    """(report, say): `report(done, total, ...)` shows progress, `say(text)` prints a line beside it."""
    if not on_terminal():
        yield PlainProgress(label, unit), typer.echo
        return
    with progress_bar() as bar:
        task = bar.add_task(label, total=None, rate="")

        def report(done: int, total: int | None, *details) -> None:
            if done % 5 == 0 or done == total:
                elapsed = bar.tasks[task].elapsed or 1e-9
                bar.update(task, completed=done, total=total, rate=f"{done / elapsed:.0f} {unit}/s")

        yield report, bar.console.print
