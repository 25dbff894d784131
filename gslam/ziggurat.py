"""Standard normal float32 numbers from a Generator's raw bits, by the ziggurat method, compiled (docs/SPEED.md).

numpy's `Generator.standard_normal(dtype=float32)` costs about 9 ns a number on the reference machine
(each number a call through the bit generator's function pointer): the 108 000 numbers of an update on
intel at N 30 took a millisecond of processor time, 4 % of the whole run. Here the bits come from the
same seeded Generator, 64 at a time (`bit_generator.random_raw`, about 1.5 ns each), and a compiled loop
turns them into normals, about 2 ns a number.

The method (Marsaglia & Tsang 2000) with 256 layers of equal area v under f(x) = exp(-x^2 / 2) on x >= 0:
edges r = x_1 > x_2 > ... > x_255 > x_256 = 0, layer i >= 1 the box [0, x_i] x [f(x_i), f(x_(i+1))],
layer 0 the box [0, r] x [0, f(r)] with the tail beyond r (width q = v / f(r) as a box). Each 32-bit
word gives the layer (8 bits), the sign (1) and u (23 bits); x = u x_i (u in [0, 1), q for layer 0) is
returned when x < x_(i+1), under the curve for any height in the layer (99 % of numbers); else layer 0
samples the tail by Marsaglia's (1964) exponential method and layer i >= 1 takes x if a uniform height
in its box falls under f(x). The edges are computed here from r (v = r f(r) + the tail's area).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

LAYERS = 256
R = 3.6541528853610088
"""The base layer's edge for 256 layers (Marsaglia & Tsang 2000)."""


def _edges() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(width scale of each layer per unit of u, the edge below which a point of layer i is accepted at
    once, f at each layer's edge), for i < LAYERS."""
    f_r = math.exp(-0.5 * R * R)
    v = R * f_r + math.sqrt(math.pi / 2) * math.erfc(R / math.sqrt(2))  # each layer's area
    x = np.empty(LAYERS + 1)  # x[i]: the right edge of layer i (x[0] = q, the base layer as a box)
    x[0], x[1] = v / f_r, R
    for i in range(1, LAYERS - 1):
        x[i + 1] = math.sqrt(-2.0 * math.log(math.exp(-0.5 * x[i] * x[i]) + v / x[i]))
    x[LAYERS] = 0.0
    width = x[:LAYERS] / (1 << 23)  # x = u * width, u the 23-bit integer
    return width, x[1:].copy(), np.exp(-0.5 * x * x)


WIDTH, ACCEPT, F = _edges()


@njit(cache=True, inline="always")
def _uniform(word):
    """A uniform number in (0, 1) from a 32-bit word (24 bits, centred: never 0 or 1)."""
    return ((word >> np.uint32(8)) + 0.5) * (1.0 / (1 << 24))


@njit(cache=True, nogil=True)
def fill_normals(words: np.ndarray, out: np.ndarray) -> int:
    """Fill out (float32, flat) with standard normals made from the 32-bit `words` in turn; returns how many
    were filled (fewer than len(out) only when the words ran out: the number being made is dropped)."""
    pos = 0
    count = words.shape[0]
    for t in range(out.shape[0]):
        while True:
            if pos >= count:
                return t
            word = words[pos]
            pos += 1
            i = word & np.uint32(0xFF)
            x = (word >> np.uint32(9)) * WIDTH[i]
            if x < ACCEPT[i]:
                break
            if i == 0:  # the tail beyond R: x = R + E1 / R for exponentials E1, E2 with 2 E2 > (E1 / R)^2
                while True:
                    if pos + 2 > count:
                        return t
                    e1 = -math.log(_uniform(words[pos])) / R
                    e2 = -math.log(_uniform(words[pos + 1]))
                    pos += 2
                    if e2 + e2 > e1 * e1:
                        break
                x = R + e1
                break
            if pos >= count:
                return t
            height = F[i] + _uniform(words[pos]) * (F[i + 1] - F[i])
            pos += 1
            if height < math.exp(-0.5 * x * x):
                break
        out[t] = -x if word & np.uint32(0x100) else x
    return out.shape[0]


def standard_normals(rng: np.random.Generator, out: np.ndarray) -> None:
    """Fill `out` (float32, C-contiguous) with standard normals from `rng`'s bit generator: its raw words
    are drawn in blocks (2 % more than the numbers, plus 64: a second block is rarely needed)."""
    if out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError("standard_normals fills a C-contiguous float32 array")
    flat = out.reshape(-1)  # a view: the array is contiguous
    done = 0
    while done < len(flat):
        need = len(flat) - done
        words = rng.bit_generator.random_raw(need // 2 + need // 100 + 64).view(np.uint32)
        done += fill_normals(words, flat[done:])
