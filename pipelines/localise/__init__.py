"""`gslam localise`: Monte Carlo localisation of a log in a saved map (core: gslam.localise)."""
