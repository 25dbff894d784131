"""Pipelines: stream MCAP logs through the filter core and write MCAP and Rerun results.

The main path is `process.process` (`gslam process`); `methods` lists the SLAM methods. Below: `run`
(the input and the runner), `outputs` (the writers), `evaluation`, `bench`, `cli`, `demo`
(docs/ARCHITECTURE.md)."""

import os

# NumPy's OpenBLAS starts a thread per core when numpy is imported, and those threads spin for a while
# after start-up and after any BLAS call, taking a core from the filter's compiled loops; nothing a
# pipeline runs needs more than one thread of BLAS (small matrices only). A user's own setting is kept,
# and a process that imported numpy before this keeps its threads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
