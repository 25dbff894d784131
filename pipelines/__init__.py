"""Pipelines: stream MCAP logs through the filter core and write MCAP and Rerun results."""
