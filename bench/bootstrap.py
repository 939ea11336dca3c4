"""Bootstrap intervals through scipy.stats.bootstrap: of a ratio of two samples' statistics (the
pixel study's variance ratios, the stability study's error ratios, the efficiency study's MSE
ratios over seeds) and of one sample's statistic (the error bars of the analytic and pixel
studies' std, RMSE and variance points).

Percentile intervals, not BCa: BCa's acceleration is a jackknife estimate, and the jackknife
is inconsistent for the median, one of the stability study's two metrics; it also costs R
statistics of R - 1 runs per ratio (36 M values at that study's 6,000 runs, for each of about
100 ratios). The percentile interval is what both studies reported before, so their verdicts
stay comparable. Runs are resampled jointly when the two samples pair up (the i-th runs share
their draws), else each sample on its own; the caller's seeded Generator makes it reproducible.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.stats import bootstrap

CONFIDENCE = 0.95
BATCH = 100  # resamples at a time: bounds the memory to 100 copies of the runs
TINY = 1e-300  # smallest denominator: a statistic of zero gives a huge ratio, not inf or NaN

# statistic(runs, axis) -> the statistic along that axis
Statistic = Callable[..., np.ndarray]


def ratio_interval(
    a: np.ndarray,
    b: np.ndarray,
    statistic: Statistic,
    rng: np.random.Generator,
    *,
    paired: bool,
    resamples: int,
) -> tuple[float, float, float]:
    """statistic(a) / statistic(b) and its 95 % percentile bootstrap interval (low, high), from
    `resamples` resamples of the runs with replacement."""

    def ratio(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
        return statistic(x, axis=axis) / np.maximum(statistic(y, axis=axis), TINY)

    with np.errstate(over="ignore"):  # scipy's standard error squares ratios near 1 / TINY
        result = bootstrap(
            (a, b),
            ratio,
            n_resamples=resamples,
            batch=BATCH,
            vectorized=True,
            paired=paired,
            axis=-1,
            confidence_level=CONFIDENCE,
            method="percentile",
            rng=rng,
        )
    interval = result.confidence_interval
    return float(ratio(a, b)), float(interval.low), float(interval.high)


def statistic_interval(
    sample: np.ndarray,
    statistic: Statistic,
    rng: np.random.Generator,
    *,
    resamples: int,
    axis: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """The 95 % percentile bootstrap interval (low, high) of statistic(sample) along `axis`
    (the runs), from `resamples` resamples of the runs with replacement; one interval per
    remaining index (e.g. per function column)."""
    with np.errstate(over="ignore", invalid="ignore"):
        result = bootstrap(
            (sample,),
            statistic,
            n_resamples=resamples,
            batch=BATCH,
            vectorized=True,
            axis=axis,
            confidence_level=CONFIDENCE,
            method="percentile",
            rng=rng,
        )
    interval = result.confidence_interval
    return np.asarray(interval.low), np.asarray(interval.high)
