"""Steps 2 to 4 of the algorithm (new points, the update of eq. 7, pruning), in two implementations.

- `windowed`: compiled, each particle touching only the points in a window around the scan, for the
  default reading of the open points. The default path.
- `wholemap`: numpy over whole maps, for every reading of the open points. The reference.

Each module says which settings it covers (`supports(cfg)`) and which it reads (`options(cfg)`);
`select` routes a filter to the compiled one wherever it supports the settings. tests/test_mapupdate.py
checks that the two agree on a scan for the default settings, and that no setting the compiled kernel
ignores is routed to it.
"""

from __future__ import annotations

from gslam.config import FilterConfig
from gslam.mapupdate import wholemap, windowed


def select(cfg: FilterConfig, threads: int = 1) -> windowed.WindowedUpdate | wholemap.WholeMapUpdate:
    """The implementation for cfg: compiled where `windowed.supports(cfg)`, else numpy over whole maps."""
    if windowed.supports(cfg):
        return windowed.WindowedUpdate(cfg, threads)
    return wholemap.WholeMapUpdate(cfg)
