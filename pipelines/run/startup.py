"""Start-up of the compiled kernels in a `gslam` command's process."""

from __future__ import annotations

import gc
import sys


def skip_blas_probe() -> None:
    """Spare numba's BLAS probe: at its first compilation or cache load numba imports its NumPy
    registries, whose `numba.np.arraymath` imports `scipy.linalg.cython_blas` to see whether `np.dot`
    and `np.linalg` can be compiled. That import loads `scipy.linalg`, a noticeable part of a run's start
    (docs/SPEED.md), and no kernel of gslam uses linear algebra. The registries are imported here with the
    probe's module marked missing, then the mark is removed, so `scipy.linalg` imports as usual later.

    Called by the CLI's commands, not on `import gslam`: in a process of the user's own, their compiled
    code may want `np.dot`. Does nothing once numba's registries or `scipy.linalg` are loaded."""
    probe = "scipy.linalg.cython_blas"
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules or probe in sys.modules:
        return
    sys.modules[probe] = None  # type: ignore[assignment]  # an import of it raises ImportError
    try:
        import numba.np.arraymath  # noqa: F401
    finally:
        del sys.modules[probe]


def freeze_heap() -> None:
    """Leave every object alive now out of the cyclic garbage collector (`gc.freeze`), for a process
    about to exit. Numba's compiler keeps hundreds of thousands of objects (its typing and lowering
    registries, loaded at the first dispatch of a compiled kernel); the interpreter's teardown would walk
    them all (docs/SPEED.md has the cost). Frozen objects are still freed by their reference counts,
    and `atexit` handlers, `weakref.finalize` callbacks and file flushes run as before: only the
    collector's walk over them is skipped.

    Called by the `gslam` script before its command and when it has returned, never by the library."""
    gc.freeze()
