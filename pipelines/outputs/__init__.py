"""What a run writes: the result MCAP (`mcap_result`), the Rerun recording (`rerun_result`, written by
`rerun_process` through `writer_process`), navigation maps (`navigation_map`, `occupancy_grid`) and the
exports for other tools (`export`); `path_checks` keeps every output off the inputs."""
