"""The new points' noise drawn in shares by parallel threads (gslam.mapupdate.noise)."""

from __future__ import annotations

import numpy as np

from gslam.mapupdate.noise import SHARES, NoiseDraws, share_bounds
from gslam.ziggurat import standard_normals


def test_the_shares_cover_the_particles_once():
    for n in range(0, 12):
        bounds = share_bounds(n)
        assert len(bounds) == SHARES and bounds[0][0] == 0 and bounds[-1][1] == n
        assert all(b0[1] == b1[0] for b0, b1 in zip(bounds, bounds[1:], strict=False))
        sizes = [b - a for a, b in bounds]
        assert max(sizes) - min(sizes) <= 1


def test_the_draws_depend_on_the_seed_not_on_the_threads():
    shape = (7, 50, 10, 2)
    runs = {}
    for threads in (1, 2, 3):
        rng = np.random.default_rng(5)
        draws = NoiseDraws(threads)
        runs[threads] = [draws.draw(rng, shape).copy() for _ in range(3)]
    for threads in (2, 3):
        for a, b in zip(runs[1], runs[threads], strict=True):
            np.testing.assert_array_equal(a, b)
    first, second, third = runs[1]
    assert first.dtype == np.float32 and first.shape == shape
    assert not np.array_equal(first, second) and not np.array_equal(second, third)  # fresh draws each update
    # each share is its own spawned generator's stream
    children = np.random.default_rng(5).spawn(SHARES)
    for g, (a, b) in zip(children, share_bounds(shape[0]), strict=True):
        expected = np.empty((b - a, *shape[1:]), dtype=np.float32)
        standard_normals(g, expected)
        np.testing.assert_array_equal(first[a:b], expected)
    other = NoiseDraws(2).draw(np.random.default_rng(6), shape)
    assert not np.array_equal(first, other)


def test_the_draws_are_standard_normals():
    x = NoiseDraws(2).draw(np.random.default_rng(0), (30, 180, 10, 2)).astype(float)
    assert abs(x.mean()) < 0.01 and abs(x.std() - 1.0) < 0.01
    assert abs(np.corrcoef(x[:15].ravel()[:50_000], x[15:].ravel()[:50_000])[0, 1]) < 0.02  # shares independent


def test_a_buffer_smaller_than_the_last_is_a_view_of_it_and_the_shapes_follow():
    draws = NoiseDraws(2)
    rng = np.random.default_rng(1)
    big = draws.draw(rng, (4, 20, 3, 2))
    small = draws.draw(rng, (3, 5, 3, 2))
    assert small.shape == (3, 5, 3, 2) and np.shares_memory(big, small)
    assert draws.draw(rng, (1, 5, 3, 2)).shape == (1, 5, 3, 2)  # one particle: one share is empty
