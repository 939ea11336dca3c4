"""The benches' bootstrap intervals (bench/bootstrap.py, scipy.stats.bootstrap): seeded, paired
where runs share draws, and covering a known ratio."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from bootstrap import ratio_interval  # noqa: E402


def variance(runs, axis=-1):
    return np.var(runs, axis=axis, ddof=1)


def rmse(errors, axis=-1):
    return np.sqrt(np.mean(errors**2, axis=axis))


def test_a_seed_gives_the_same_interval():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=200), rng.normal(size=150)  # unequal lengths: independent runs

    def interval(seed):
        return ratio_interval(
            a, b, variance, np.random.default_rng(seed), paired=False, resamples=500
        )

    assert interval(7) == interval(7)
    assert interval(7) != interval(8)


def test_the_interval_is_the_percentile_interval_the_studies_computed_before():
    # The hand-written resampling it replaces: runs drawn with replacement, the 2.5 and 97.5
    # percentiles of the ratios; the two agree to their Monte Carlo error
    rng = np.random.default_rng(1)
    a, b = rng.normal(scale=2.0, size=400), rng.normal(size=300)
    ia, ib = rng.integers(0, len(a), (4000, len(a))), rng.integers(0, len(b), (4000, len(b)))
    before = np.percentile(variance(a[ia]) / variance(b[ib]), [2.5, 97.5])
    ratio, lo, hi = ratio_interval(a, b, variance, rng, paired=False, resamples=4000)
    assert ratio == a.var(ddof=1) / b.var(ddof=1)
    assert lo == pytest.approx(before[0], rel=0.03) and hi == pytest.approx(before[1], rel=0.03)
    assert lo < ratio < hi


def test_paired_resampling_narrows_the_interval_of_runs_that_share_draws():
    # Two estimators of the same draws: their errors move together, and only a paired
    # resample keeps that (an independent one sees two unrelated spreads)
    rng = np.random.default_rng(2)
    shared = rng.normal(size=500)
    a, b = 1.05 * shared + 0.05 * rng.normal(size=500), shared
    _, plo, phi = ratio_interval(a, b, rmse, np.random.default_rng(3), paired=True, resamples=1000)
    _, ilo, ihi = ratio_interval(a, b, rmse, np.random.default_rng(3), paired=False, resamples=1000)
    assert plo > 1.0  # paired: a's error is significantly larger
    assert ilo < 1.0 < ihi  # independent: no verdict
    assert (phi - plo) < 0.2 * (ihi - ilo)


def test_a_zero_statistic_in_a_resample_gives_a_large_ratio_not_nan():
    a = np.array([1.0, 2.0, 3.0, 4.0])
    b = np.array([0.0, 0.0, 0.0, 1e-3])  # many resamples of b have variance 0
    ratio, lo, hi = ratio_interval(
        a, b, variance, np.random.default_rng(4), paired=False, resamples=200
    )
    assert np.isfinite([ratio, lo, hi]).all() and hi > 1e100


def test_the_stability_atlas_keeps_its_keys():
    pytest.importorskip("matplotlib")
    stability_study = pytest.importorskip("stability_study")
    rng = np.random.default_rng(5)
    errors, base = rng.normal(size=300), rng.normal(size=300)
    cell = stability_study.ratio_ci(errors, base, "median |error|", rng, paired=False)
    assert set(cell) == {"metric", "value", "baseline", "ratio", "lo", "hi"}
    assert cell["lo"] < cell["ratio"] < cell["hi"]
