"""The per-pixel variance layer: how noisy each pixel's samples are, as the mc estimator sees
them.

For every estimator of a render, the layer holds the variance the mc estimator (sum f / n) has
over the pixel's traced samples, estimated from those samples alone:

- Poisson counts (sppp, sppp-sobol): mc = sum f / n is a compound Poisson sum, whose variance
  E[f^2] / n is estimated without bias by sum f^2 / n^2;
- a fixed count N = n (every other sampler): Var(mean) = sigma^2 / n, estimated by s^2 / n with
  s^2 the unbiased sample variance (n >= 2; NaN for n = 1: one sample says nothing of it).

It is the variance of mc itself for independent samples (the independent sampler, and sppp's
Poisson positions with independent path dimensions). Over stratified or Sobol samples it is
what independent samples of the pixel would give: their own variance is lower, typically far
lower. For the Voronoi estimators it is the same mc figure of the same samples, not their own
variance: their cells couple the samples, and one draw gives no unbiased estimate of it (use
several seeds). Non-finite radiance counts as 0, as in the estimators.

`noise_mse` (the mean of the layer over pixels and channels) is the estimator's own expected
squared error only where the layer is its unbiased variance: mc over independent or sppp
samples, mc_n over independent ones (N = n). A render writes it into its EXR's metadata only
then, and `clrender.compare` subtracts it when that EXR serves as a reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clrender.estimators.pixel import pixel_sums
from clrender.estimators.registry import Estimator
from clrender.samples import SampleSets
from clrender.sampling import PATHS_INDEPENDENT, POSITIONS_INDEPENDENT, SamplerConfig


@dataclass
class PixelMoments:
    """Per pixel: traced samples N, sum f and sum f^2 ((P, 3) float64, non-finite as 0)."""

    counts: np.ndarray
    value: np.ndarray
    square: np.ndarray

    @classmethod
    def of_samples(cls, sets: SampleSets, values: np.ndarray) -> PixelMoments:
        """From host samples: values (T, 3) float64 with non-finite rows already zeroed (summed
        in sample order, as the estimators and the device sums do)."""
        counts = np.asarray(sets.counts, np.int64)
        return cls(counts, pixel_sums(sets, values), pixel_sums(sets, values * values))

    def subset(self, rows: np.ndarray) -> PixelMoments:
        return PixelMoments(self.counts[rows], self.value[rows], self.square[rows])


def mc_variance(moments: PixelMoments, sampler: SamplerConfig) -> np.ndarray:
    """(P, 3) float32: the estimated variance of the mc estimate of each pixel (see above)."""
    n = float(sampler.n)
    if sampler.is_sppp:
        variance = moments.square / (n * n)
    else:
        counts = np.maximum(moments.counts, 1).astype(np.float64)[:, None]
        spread = moments.square - moments.value * moments.value / counts
        with np.errstate(divide="ignore", invalid="ignore"):
            variance = np.maximum(spread, 0.0) / (counts * (counts - 1.0))
        variance = np.where(counts >= 2, variance, np.nan)
    return variance.astype(np.float32)


def variance_is_unbiased(estimator: Estimator, sampler: SamplerConfig) -> bool:
    """Whether the layer is this estimator's own unbiased variance over this sampler."""
    kind = sampler.kind
    independent = kind.paths == PATHS_INDEPENDENT and (
        kind.positions == POSITIONS_INDEPENDENT or kind.is_sppp
    )
    if estimator.name == "mc":
        return independent
    return estimator.name == "mc_n" and independent and not kind.is_sppp
