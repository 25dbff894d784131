"""`gslam demo`: a simulated Car Park-like log (`world`), ingested, processed, evaluated and plotted (`run`)."""

from pipelines.demo.run import run_demo, write_sydney_text

__all__ = ["run_demo", "write_sydney_text"]
