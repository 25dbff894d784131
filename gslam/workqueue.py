"""Dynamic scheduling of the particle loops: workers take the next particle as they become free.

numba's `prange` hands each thread a fixed share of the iterations; a worker whose core is taken for a
moment (the Rerun writer's process, another program on a shared machine) then holds up the whole loop
while the others wait. The compiled particle loops instead start one iteration per worker, and each
worker takes particle indices from a shared counter (`next_index`, an atomic fetch-and-add) until none
is left (measured in docs/SPEED.md). Every particle's result depends only on its own inputs (each
worker's scratch arrays are reset after every particle), so the results do not depend on which worker
took which particle, nor on the number of threads.
"""

from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def next_index(typingctx, counter):  # pragma: no cover - compiled
    """counter[0] += 1 atomically; returns the value before (an int64 array of one element)."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64):
        return None
    sig = types.int64(counter)

    def codegen(context, builder, signature, args):
        arr_t = signature.args[0]
        arr = context.make_array(arr_t)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, arr_t, arr, [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, context.get_constant(types.int64, 1), "monotonic")

    return sig, codegen
