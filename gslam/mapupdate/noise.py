"""The new points' noise of step 2 (z_hat ~ N(z, R)), drawn in parallel.

Every update draws M x 2 standard normals for every particle and return (30 x 180 x 10 x 2 on intel at
N 30). The particles are cut into `SHARES` fixed shares, each drawn by a generator of its own, spawned
once from the filter's seeded Generator (`numpy.random.Generator.spawn`), and the shares are drawn by
parallel threads. Each share's numbers are made from its generator's raw bits by the compiled ziggurat
of `gslam.ziggurat` (0.4 ms of one thread an update on intel, against 1 ms for numpy's own sampler), which
runs without holding the GIL. The numbers depend on the seed only, not on the number of threads: with one
thread the shares are drawn in turn.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from gslam.ziggurat import standard_normals

SHARES = 2
"""Shares of the particles, each drawn by its own generator (fixed, so the draws do not depend on the
threads)."""


def share_bounds(n: int, shares: int = SHARES) -> list[tuple[int, int]]:
    """The particle rows [a, b) of each share: as equal as can be, the first ones larger."""
    cuts = [(n * k + shares - 1) // shares for k in range(shares + 1)]
    return [(cuts[k], cuts[k + 1]) for k in range(shares)]


class NoiseDraws:
    """Standard normals (float32) of shape (N, R, M, 2) for the new points, from `SHARES` generators
    spawned from the filter's at the first draw, filled by up to `threads` threads, into a buffer reused
    from one update to the next (the caller uses the array before the next draw). `fill(generator, out)`
    fills one share's rows (`gslam.ziggurat.standard_normals`)."""

    def __init__(
        self, threads: int, fill: Callable[[np.random.Generator, np.ndarray], None] = standard_normals
    ) -> None:
        self.threads = max(1, int(threads))
        self.fill = fill
        self._pool: ThreadPoolExecutor | None = None
        self._parent: np.random.Generator | None = None
        self._shares: list[np.random.Generator] = []
        self._buffer = np.empty(0, dtype=np.float32)

    def draw(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        if rng is not self._parent:
            self._parent, self._shares = rng, list(rng.spawn(SHARES))
        size = int(np.prod(shape))
        if self._buffer.size < size:
            self._buffer = np.empty(int(size * 1.25) + 1, dtype=np.float32)
        out = self._buffer[:size].reshape(shape)
        parts = [(g, out[a:b]) for g, (a, b) in zip(self._shares, share_bounds(shape[0]), strict=True) if b > a]
        if self.threads == 1 or len(parts) == 1:
            for g, part in parts:
                self.fill(g, part)
            return out
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=min(self.threads, SHARES) - 1, thread_name_prefix="noise")
        pending = [self._pool.submit(self.fill, g, part) for g, part in parts[1:]]
        self.fill(*parts[0])
        for p in pending:
            p.result()
        return out
