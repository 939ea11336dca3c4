"""Pixel estimators: every pixel's integral from its samples, Monte Carlo or Voronoi-weighted.

Modules in the order data flows through them:
  registry      every estimator (name, meaning, needs, cells, formula): the one table
  pixel         per-pixel estimation: tessellations, per-pixel sums, the formulas applied
  delaunay      cell areas from a Delaunay triangulation (shared by qhull_cells and image)
  qhull_cells   per-pixel cells by SciPy's Qhull, many pixels per call
  device_cells  per-pixel SPPP cells and sums on the OpenCL device
  image         image-level estimators: one tessellation of every pixel's nuclei
  redraw        the paper's rejection: bounded redraws of pixels with an unbounded cell
  variance      the per-pixel variance layer (the mc estimate's, from the same samples)
"""

from clrender.estimators.pixel import EstimateResult, EstimateStats, estimate, estimate_all
from clrender.estimators.redraw import RedrawOutcome, RedrawStats, estimate_with_redraw
from clrender.estimators.registry import (
    ESTIMATORS,
    Estimator,
    EstimatorWarning,
    PixelSums,
    check_compatible,
    estimator_info,
    pairing_advice,
)

__all__ = [
    "ESTIMATORS",
    "EstimateResult",
    "EstimateStats",
    "Estimator",
    "EstimatorWarning",
    "PixelSums",
    "RedrawOutcome",
    "RedrawStats",
    "check_compatible",
    "estimate",
    "estimate_all",
    "estimate_with_redraw",
    "estimator_info",
    "pairing_advice",
]
