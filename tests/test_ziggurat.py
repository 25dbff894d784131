"""The compiled standard normals (gslam.ziggurat) and exp (gslam.fastmath) the filter's kernels use."""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy import stats

from gslam.fastmath import fast_exp
from gslam.ziggurat import ACCEPT, LAYERS, WIDTH, F, R, fill_normals, standard_normals


def test_the_layers_have_equal_areas_and_close_at_the_peak():
    x = WIDTH * (1 << 23)  # each layer's right edge (the base layer's as a box of its area)
    v = R * math.exp(-0.5 * R * R) + math.sqrt(math.pi / 2) * math.erfc(R / math.sqrt(2))
    assert x[0] * F[1] == np.float64(x[0] * math.exp(-0.5 * R * R))
    areas = x[1:] * (F[2 : LAYERS + 1] - F[1:LAYERS])  # layer i >= 1: [0, x_i] x [f(x_i), f(x_(i+1))]
    np.testing.assert_allclose(areas, v, rtol=1e-9)
    assert F[LAYERS] == 1.0 and np.all(np.diff(x[1:]) < 0) and np.all(ACCEPT < x)


def test_the_numbers_are_standard_normal():
    out = np.empty(4_000_000, dtype=np.float32)
    standard_normals(np.random.default_rng(3), out)
    x = out.astype(float)
    assert abs(x.mean()) < 0.003 and abs(x.std() - 1.0) < 0.002
    assert stats.kstest(x[:1_000_000], "norm").pvalue > 1e-3
    for t in (1.0, 2.0, 3.0, R, 4.0):  # the tail beyond R is sampled its own way: its mass as well
        expected = 2 * stats.norm.sf(t)
        assert abs((np.abs(x) > t).mean() - expected) < 5 * math.sqrt(expected / len(x)) + 1e-6
    assert abs(np.corrcoef(x[:-1], x[1:])[0, 1]) < 0.003  # successive numbers independent


def test_the_numbers_depend_on_the_seed_and_survive_running_out_of_words():
    a = np.empty(10_001, dtype=np.float32)
    b = np.empty(10_001, dtype=np.float32)
    standard_normals(np.random.default_rng(7), a)
    standard_normals(np.random.default_rng(7), b)
    np.testing.assert_array_equal(a, b)
    words = np.random.default_rng(1).bit_generator.random_raw(100).view(np.uint32)  # 200 words
    out = np.full(1000, np.nan, dtype=np.float32)
    filled = fill_normals(words, out)
    assert 150 < filled < 200 and np.isfinite(out[:filled]).all() and np.isnan(out[filled:]).all()


@njit
def _both(xs, a, b):
    for i in range(xs.shape[0]):
        a[i] = math.exp(xs[i])
        b[i] = fast_exp(xs[i])


def test_fast_exp_is_within_one_unit_in_the_last_place_of_the_c_library():
    rng = np.random.default_rng(0)
    special = [0.0, -0.0, 1e-300, -1e-20, 2.0**-54, -(2.0**-54), 511.9, -511.9, 512.0, -745.2, 709.7, -1000.0]
    xs = np.concatenate([-rng.random(2_000_000) * 50, -rng.random(200_000) * 700, rng.random(200_000) * 5, special])
    a, b = np.empty_like(xs), np.empty_like(xs)
    _both(xs, a, b)
    ulps = np.abs(a.view(np.int64) - b.view(np.int64))
    assert ulps.max() <= 1 and (ulps == 0).mean() > 0.99
    edge = np.array([np.inf, -np.inf, np.nan, 1e6, -1e6])
    a, b = np.empty_like(edge), np.empty_like(edge)
    _both(edge, a, b)
    np.testing.assert_array_equal(a, b)  # outside the table's range: math.exp itself
