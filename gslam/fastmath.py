"""exp for the compiled loops, inlined where it is used (docs/SPEED.md).

numba calls the C library's exp through two wrappers (numba's `numba_exp`, then glibc's compatibility
`exp` that checks for overflow to set errno): on intel's whole run exp took 11 % of all processor time,
most of it in the matcher's score, one exp per return and candidate pose. This is the usual
table-driven method, inlined: x = k ln2 / N + r with N = 128, |r| <= ln2 / 2N (k rounded by adding
1.5 x 2^52, r by a two-part ln2 / N: the high part's k multiple is exact), exp(x) = 2^(k/N) (1 + tail)
exp(r), the 128 values 2^(i/N) and their rounding errors (tail) tabulated here from their definition
at 60 digits, exp(r) - 1 by its degree-5 Taylor polynomial (error below 2^-60 relative on |r| <= ln2 / 256).
Within one unit in the last place of the C library's (identical on 99.9 % of 13 million arguments over
[-700, 5], tests/test_ziggurat.py); arguments outside 2^-54 <= |x| < 512 (0, tiny, huge, inf, nan)
take math.exp itself.
"""

from __future__ import annotations

import math
from decimal import Decimal, localcontext

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

TABLE_BITS = 7
N = 1 << TABLE_BITS


def _bits(x: float) -> int:
    return int(np.array([x], dtype=np.float64).view(np.uint64)[0])


def _float(bits: int) -> float:
    return float(np.array([bits], dtype=np.uint64).view(np.float64)[0])


def _table() -> np.ndarray:
    """(tail_i bits, bits of 2^(i/N) minus i << (52 - TABLE_BITS)) for i < N, interleaved: adding k << (52 -
    TABLE_BITS) to the second (k = i mod N) gives the bits of 2^(k/N)."""
    out = np.empty(2 * N, dtype=np.uint64)
    with localcontext() as ctx:
        ctx.prec = 60
        for i in range(N):
            exact = Decimal(2) ** (Decimal(i) / N)
            scale = float(exact)
            out[2 * i] = _bits(float((exact - Decimal(scale)) / Decimal(scale)))
            out[2 * i + 1] = (_bits(scale) - (i << (52 - TABLE_BITS))) % (1 << 64)
    return out


def _ln2_parts() -> tuple[float, float]:
    """ln2 / N as hi + lo, hi with its low 24 bits zero (so k hi is exact for |k| < 2^24)."""
    with localcontext() as ctx:
        ctx.prec = 60
        c = Decimal(2).ln() / N
        hi = _float(_bits(float(c)) & ~((1 << 24) - 1))
        return hi, float(c - Decimal(hi))


TABLE = _table()
INV_LN2_N = float(N / Decimal(2).ln())
SHIFT = 1.5 * 2.0**52
LN2_HI_N, LN2_LO_N = _ln2_parts()
C2, C3, C4, C5 = 1.0 / 2.0, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0


@intrinsic
def _as_uint64(typingctx, x):  # pragma: no cover - compiled
    """The bits of a float64."""
    if x != types.float64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.uint64(types.float64), codegen


@intrinsic
def _as_float64(typingctx, x):  # pragma: no cover - compiled
    """The float64 of some bits."""
    if x != types.uint64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.uint64), codegen


@njit(cache=True, inline="always")
def fast_exp(x):
    """exp(x), within one unit in the last place (see the module's docstring)."""
    top = (_as_uint64(x) >> np.uint64(52)) & np.uint64(0x7FF)
    if top - np.uint64(0x3C9) >= np.uint64(0x408 - 0x3C9):  # |x| < 2^-54 or >= 512, inf, nan
        return math.exp(x)
    kd = x * INV_LN2_N + SHIFT  # k = round(x N / ln2) in the low bits
    ki = _as_uint64(kd)
    kd -= SHIFT
    r = x - kd * LN2_HI_N - kd * LN2_LO_N
    i = np.uint64(2) * (ki % np.uint64(N))
    tail = _as_float64(TABLE[i])
    scale = _as_float64(TABLE[i + np.uint64(1)] + (ki << np.uint64(52 - TABLE_BITS)))
    r2 = r * r
    p = tail + r + r2 * (C2 + r * C3) + r2 * r2 * (C4 + r * C5)
    return scale + scale * p
