"""G-SLAM filter core: pure numpy/scipy, arrays in and arrays out (no files, MCAP or Rerun)."""

import os

# The compiled particle loops run on numba's OpenMP threads. By default an idle OpenMP thread spins
# waiting for the next parallel loop, taking a core from the Python thread (input, outputs) and from
# the Rerun writer's threads between the filter's updates (docs/SPEED.md). A user's own setting is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
