"""What a run writes: the result MCAP (`mcap_result`), the Rerun recording (`rerun_result`, written by
`rerun_recorder` through `writer_child`), navigation maps (`navigation_map`, `occupancy_grid`) and the
exports for other tools (`export`); `path_checks` keeps every output off the inputs."""
