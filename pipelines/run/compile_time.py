"""Time spent compiling the filter's numba kernels, kept out of the recorded step times.

The kernels are compiled on a machine's first run and loaded from numba's cache after (`cache=True`); a
compile takes 15 to 30 s on 2 cores, inside the first steps that call each kernel. `CompileWatch` listens
to numba's own "numba:compile" events: it calls `on_first` as the first compile starts (so the user is
told why the bar waits), sums the seconds of every outermost compile, and lets the run subtract them from
the step they fell in, so a first run's timings are those of any other run. Loading from the cache
raises no such event and is timed as the filter's own work.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

COMPILING_NOTE = "compiling the filter's kernels (first run only: 15 to 30 s; later runs load them from a cache)"


class CompileWatch:
    """Seconds of numba compilation so far (`total_s`), counted once per outermost compile."""

    def __init__(self, on_first: Callable[[], None] | None = None) -> None:
        self.total_s = 0.0
        self.compiles = 0
        self.on_first = on_first
        self._depth = 0
        self._t0 = 0.0

    def on_start(self, event) -> None:
        if self._depth == 0:
            if self.compiles == 0 and self.on_first is not None:
                self.on_first()
            self._t0 = time.perf_counter()
        self._depth += 1

    def on_end(self, event) -> None:
        self._depth -= 1
        if self._depth == 0:
            self.total_s += time.perf_counter() - self._t0
            self.compiles += 1


@contextmanager
def watching_compiles(on_first: Callable[[], None] | None = None) -> Iterator[CompileWatch]:
    """A `CompileWatch` listening to numba's compile events within the block."""
    from numba.core import event

    watch = CompileWatch(on_first)

    class _Listener(event.Listener):
        def on_start(self, ev) -> None:
            watch.on_start(ev)

        def on_end(self, ev) -> None:
            watch.on_end(ev)

    with event.install_listener("numba:compile", _Listener()):
        yield watch
