"""The new points' noise of step 2 (z_hat ~ N(z, R)), drawn in parallel.

Every update draws M x 2 standard normals for every particle and return (30 x 180 x 10 x 2 on intel at
N 30, about a millisecond of one thread). The particles are cut into `SHARES` fixed shares, each drawn by
a generator of its own, spawned once from the filter's seeded Generator (`numpy.random.Generator.spawn`),
and the shares are drawn by parallel threads: numpy fills an array without holding the GIL. The numbers
depend on the seed only, not on the number of threads: with one thread the shares are drawn in turn.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

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
    from one update to the next (the caller uses the array before the next draw)."""

    def __init__(self, threads: int) -> None:
        self.threads = max(1, int(threads))
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
                g.standard_normal(dtype=np.float32, out=part)
            return out
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=min(self.threads, SHARES) - 1, thread_name_prefix="noise")
        pending = [self._pool.submit(g.standard_normal, dtype=np.float32, out=part) for g, part in parts[1:]]
        parts[0][0].standard_normal(dtype=np.float32, out=parts[0][1])
        for p in pending:
            p.result()
        return out
