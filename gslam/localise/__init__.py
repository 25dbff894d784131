"""Localisation in a saved map: Monte Carlo localisation on a likelihood field of the map (`mcl`, `field`,
`match`). Pure numpy / scipy / numba, like the SLAM core: arrays in, arrays out."""

from gslam.localise.field import LikelihoodField
from gslam.localise.mcl import LocaliseConfig, LocaliseStep, MonteCarloLocaliser

__all__ = ["LikelihoodField", "LocaliseConfig", "LocaliseStep", "MonteCarloLocaliser"]
