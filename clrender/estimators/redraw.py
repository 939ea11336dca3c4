"""Voronoi pixel estimation with the paper's rejection: redraw pixels whose cells are unbounded.

The entry point for callers (the renderer, the benchmarks) is estimate_with_redraw: it draws
every pixel's SPPP sample set through a callback, evaluates the samples through another,
estimates, and redraws only the pixels an estimator rejected (a W nucleus with an unbounded
cell). It always terminates:

- rounds 0 .. redraws_before_enlarge use the caller's eps (the paper's redraw);
- each later round multiplies eps by enlarge_factor (the paper's suggested remedy: a wider
  stretched window makes unbounded W cells rarer) up to clrender.sppp.MAX_EPS, and never goes
  below sppp_eps(n, alpha),
  the eps at which the paper's bound on the rejection probability is alpha: a draw accepted
  where rejection is likely is conditioned on its acceptance, and biased (measured: fvor
  z = -27 after a storm at eps = 1e-4 recovered by plain enlargement);
- after max_rounds the pixels still rejected raise ClrenderError (on_exhausted="raise"), or
  get the mc estimate of their last draw (on_exhausted="mc"), counted in the statistics.

Estimators that never reject (mc, mc_n, cvor, pvor) finish in one round. The estimators
themselves are in clrender.estimators.pixel, the registry in clrender.estimators.registry.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from clrender.errors import ClrenderError, ParameterError
from clrender.estimators.pixel import EstimateResult, estimate, estimate_all
from clrender.estimators.registry import MC, Estimator, estimator_info
from clrender.samples import SampleSets
from clrender.sppp import DEFAULT_ALPHA, MAX_EPS, sppp_eps

# draw(pixel_ids, eps) -> the sample sets of those pixels and the values of their traced samples
DrawFn = Callable[[np.ndarray, float], tuple[SampleSets, np.ndarray]]


@dataclass
class RedrawStats:
    rounds: int = 0  # estimation rounds run (1 = no redraw needed)
    redraws: int = 0  # pixel redraws, summed over rounds
    eps_enlargements: int = 0  # rounds that ran with an enlarged eps
    initial_eps: float = 0.0
    final_eps: float = 0.0
    exhausted_pixels: int = 0  # pixels still rejected after max_rounds (on_exhausted="mc")
    empty_filtered: int = 0  # fvor pixels that fell back to vor_sn
    empty_pixels: int = 0  # accepted draws with N = 0
    recomputed_pixels: int = 0  # pixels whose cells were recomputed alone (geometry check)
    settled_pixels: int = 0  # pixels Qhull could not resolve, settled by clipping
    qhull_calls: int = 0
    redraws_per_round: list[int] = field(default_factory=list)


@dataclass
class RedrawOutcome:
    estimates: dict[str, np.ndarray]  # name -> (P,) or (P, C)
    stats: RedrawStats


def estimate_with_redraw(
    names: str | Estimator | Sequence[str | Estimator],
    draw: DrawFn,
    pixels: int,
    n: float,
    *,
    eps: float | None = None,
    alpha: float = DEFAULT_ALPHA,
    redraws_before_enlarge: int = 3,
    enlarge_factor: float = 1.5,
    max_rounds: int = 12,
    on_exhausted: str = "raise",
) -> RedrawOutcome:
    """Estimate `pixels` pixels with every estimator in `names`, redrawing rejected pixels.

    draw(pixel_ids, eps) returns (SampleSets, values) for exactly those pixels (in that order)
    at stretch eps, with n' = auxiliary_count(n, eps) auxiliary nuclei, and the (T,) or (T, C)
    values of their traced samples. A pixel is redrawn when any requested estimator rejects it;
    all estimators of a pixel use the same accepted draw.
    """
    single = isinstance(names, str | Estimator)
    entries = [estimator_info(name) for name in ([names] if single else names)]
    _check_redraw_parameters(
        pixels, redraws_before_enlarge, enlarge_factor, max_rounds, on_exhausted
    )
    eps = sppp_eps(n, alpha) if eps is None else float(eps)
    stats = RedrawStats(initial_eps=eps, final_eps=eps)
    estimates: dict[str, np.ndarray] = {}
    pending = np.arange(pixels)
    samples = values = None
    for round_index in range(max_rounds):
        if pending.size == 0:
            break
        if round_index > redraws_before_enlarge:
            eps = min(max(eps * enlarge_factor, sppp_eps(n, alpha)), MAX_EPS)
            stats.eps_enlargements += 1
        samples, values = _draw(draw, pending, eps)
        results = estimate_all(entries, samples, values)
        rejected = np.logical_or.reduce([r.needs_redraw for r in results.values()])
        _store(estimates, results, pending, ~rejected, pixels)
        _count(stats, results, entries, samples, rejected, round_index, eps)
        pending = pending[rejected]
        if pending.size and round_index + 1 < max_rounds:
            stats.redraws += int(pending.size)
            stats.redraws_per_round.append(int(pending.size))
    if pending.size:
        _exhausted(estimates, samples, values, pending, stats, on_exhausted, max_rounds)
    return RedrawOutcome(estimates, stats)


def _check_redraw_parameters(
    pixels, redraws_before_enlarge, enlarge_factor, max_rounds, on_exhausted
) -> None:
    if not (isinstance(pixels, int | np.integer) and pixels >= 0):
        raise ParameterError(f"pixels must be a non-negative integer, got {pixels!r}")
    if redraws_before_enlarge < 0 or max_rounds < 1:
        raise ParameterError("redraws_before_enlarge must be >= 0 and max_rounds >= 1")
    if not enlarge_factor > 1.0:
        raise ParameterError(f"enlarge_factor must exceed 1, got {enlarge_factor!r}")
    if on_exhausted not in ("raise", "mc"):
        raise ParameterError(f"on_exhausted must be 'raise' or 'mc', got {on_exhausted!r}")


def _draw(draw: DrawFn, pixel_ids: np.ndarray, eps: float) -> tuple[SampleSets, np.ndarray]:
    samples, values = draw(pixel_ids, eps)
    if samples.pixel_count != len(pixel_ids):
        raise ParameterError(
            f"draw returned {samples.pixel_count} pixels for {len(pixel_ids)} requested"
        )
    return samples, np.asarray(values, dtype=np.float64)


def _store(estimates, results, pending, accepted, pixels) -> None:
    for name, result in results.items():
        if name not in estimates:
            shape = (pixels,) + result.estimates.shape[1:]
            estimates[name] = np.full(shape, np.nan)
        estimates[name][pending[accepted]] = result.estimates[accepted]


def _count(
    stats: RedrawStats,
    results: dict[str, EstimateResult],
    entries: list[Estimator],
    samples: SampleSets,
    rejected: np.ndarray,
    round_index: int,
    eps: float,
) -> None:
    stats.rounds = round_index + 1
    stats.final_eps = eps
    accepted_counts = samples.counts[~rejected]
    stats.empty_pixels += int((accepted_counts == 0).sum())
    # Estimators that share a tessellation (the vor family) count it once.
    counted = set()
    for entry in entries:
        result = results[entry.name]
        if entry.kept_cells:
            stats.empty_filtered += result.stats.empty_filtered
        if entry.cells != "none" and entry.cells not in counted:
            counted.add(entry.cells)
            stats.recomputed_pixels += result.stats.tessellation.recomputed_pixels
            stats.settled_pixels += result.stats.tessellation.settled_pixels
            stats.qhull_calls += result.stats.tessellation.qhull_calls


def _exhausted(estimates, samples, values, pending, stats, on_exhausted, max_rounds) -> None:
    if on_exhausted == "raise":
        raise ClrenderError(
            f"{pending.size} pixel(s) still had an unbounded Voronoi cell after {max_rounds} "
            f"draws (final eps {stats.final_eps:.4g}); check that the sampler draws auxiliary "
            "nuclei around W, or pass on_exhausted='mc'"
        )
    # The last round's samples hold exactly the pending pixels, in order.
    fallback = estimate(MC, samples, values).estimates
    for name in estimates:
        estimates[name][pending] = fallback
    stats.exhausted_pixels = int(pending.size)
