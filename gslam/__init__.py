"""G-SLAM filter core: pure numpy/scipy, arrays in and arrays out (no files, MCAP or Rerun)."""

__version__ = "0.1.0"
