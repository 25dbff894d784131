"""Reading results: the metrics (`metrics`, `evaluate`: `gslam eval`), the figure (`plot`: `gslam plot`)
and what an MCAP file holds (`mcap_info`: `gslam info`); a localisation result's figures and figure
(`localisation`, `localisation_plot`), told from a mapping result by its metadata."""
