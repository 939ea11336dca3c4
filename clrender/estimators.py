"""Per-pixel integral estimators over W = [-1/2, 1/2]^2: Monte Carlo and Voronoi-weighted.

Every estimator takes a batch of pixels' samples (PixelSamples: positions in W, one value per
sample, scalar or RGB, optional auxiliary nuclei) and returns one estimate per pixel, the
integral of f over W (|W| = 1, so it is also the pixel's mean value).

| name   | estimate of pixel p (sums over its N nuclei x in W)        | needs            |
|--------|------------------------------------------------------------|------------------|
| mc     | sum f(x) / n, n the Poisson intensity                      | any sampler      |
| mc_n   | sum f(x) / N (conditional form), 0 when N = 0              | any sampler      |
| vor    | E_V = sum f(x) v(x), cells of W + aux nuclei, unnormalised | SPPP aux nuclei  |
| vor_sn | sum f(x) v(x) / sum v(x), same cells (self-normalised)     | SPPP aux nuclei  |
| fvor   | E_F: like vor_sn over the nuclei whose cell lies in W'     | SPPP aux nuclei  |
| cvor   | E_C = sum f(x) |C(x) cap W|, cells of the W nuclei only    | any sampler      |
| pvor   | sum f(x) v_torus(x), cells on the torus W                  | any sampler      |

Conventions and choices:
- mc divides by the intensity n, which is unbiased when N ~ Poisson(n) (and equals the sample
  mean for fixed-count samplers, where N = n). mc_n divides by N.
- vor is the paper's E_V, *not* normalised; vor_sn (self-normalised) is what the authors'
  renderer computes and what the paper's measured "vor" column matches. They are different
  estimators and are reported under different names.
- A W nucleus with an unbounded cell (on the convex hull of W + aux nuclei) makes its pixel
  invalid for vor, vor_sn and fvor: the result's needs_redraw is set and the estimate is NaN.
  clrender.voronoi.estimate_with_redraw redraws such pixels.
- fvor with no nucleus whose cell lies in W' falls back to vor_sn for that pixel (counted in
  stats.empty_filtered).
- A pixel with N = 0 estimates 0 with every estimator (counted in stats.empty_pixels).
- A non-finite value (NaN, +-Inf) makes its pixel's estimate non-finite (fvor: only if the
  nucleus is kept); other pixels are unaffected.
- pvor: W as a torus; exactly unbiased for N i.i.d. uniform points, no aux nuclei, no rejection.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from clrender.errors import ParameterError
from clrender.sppp import SpppBatch
from clrender.voronoi_cells import (
    CellAreas,
    TessellationStats,
    clipped_cells,
    periodic_cells,
    sppp_cells,
)


@dataclass(frozen=True)
class EstimatorInfo:
    name: str
    description: str
    needs_aux: bool  # requires SPPP auxiliary nuclei (and eps)
    cells: str  # tessellation it uses: "none", "sppp", "clipped" or "periodic"


ESTIMATORS: dict[str, EstimatorInfo] = {
    info.name: info
    for info in [
        EstimatorInfo(
            "mc", "Monte Carlo: sum of values / intensity n (unbiased for Poisson N)", False, "none"
        ),
        EstimatorInfo(
            "mc_n",
            "Monte Carlo, conditional form: mean of the N values (0 if N = 0)",
            False,
            "none",
        ),
        EstimatorInfo(
            "vor",
            "Voronoi E_V: sum f(x) area(cell(x)), cells of W + auxiliary nuclei, not normalised",
            True,
            "sppp",
        ),
        EstimatorInfo(
            "vor_sn",
            "self-normalised Voronoi: sum f v / sum v over the W nuclei "
            "(the authors' renderer's 'vor')",
            True,
            "sppp",
        ),
        EstimatorInfo(
            "fvor",
            "filtered Voronoi E_F: self-normalised over the nuclei whose cell lies inside W'",
            True,
            "sppp",
        ),
        EstimatorInfo(
            "cvor",
            "clipped Voronoi E_C: cells of the W nuclei alone clipped to W (biased near edges)",
            False,
            "clipped",
        ),
        EstimatorInfo(
            "pvor",
            "periodic Voronoi: cells on the torus W (unbiased, no auxiliary nuclei, no rejection)",
            False,
            "periodic",
        ),
    ]
}


def estimator_info(name: str) -> EstimatorInfo:
    """The registry entry of `name`; ParameterError listing the accepted names otherwise."""
    try:
        return ESTIMATORS[name]
    except (KeyError, TypeError):
        raise ParameterError(
            f"unknown estimator {name!r}; accepted: {', '.join(ESTIMATORS)}"
        ) from None


@dataclass(frozen=True)
class PixelSamples:
    """A batch of pixels' samples in flat arrays (pixel-local positions in W = [-1/2, 1/2]^2).

    positions[offsets[p]:offsets[p+1]] and values[...] belong to pixel p; values are (T,) or
    (T, C). intensity is n, the expected count per pixel (mc divides by it). aux and
    aux_offsets hold the SPPP auxiliary nuclei in the strip W' minus W, eps its width.
    """

    positions: np.ndarray
    values: np.ndarray
    offsets: np.ndarray
    intensity: float
    aux: np.ndarray | None = None
    aux_offsets: np.ndarray | None = None
    eps: float | None = None

    @classmethod
    def from_sppp(cls, batch: SpppBatch, values: np.ndarray, intensity: float) -> PixelSamples:
        return cls(
            batch.traced,
            np.asarray(values, dtype=np.float64),
            batch.offsets,
            float(intensity),
            batch.aux,
            batch.aux_offsets,
            batch.eps,
        )

    @property
    def pixel_count(self) -> int:
        return len(self.offsets) - 1

    @cached_property
    def counts(self) -> np.ndarray:
        """(P,) samples per pixel."""
        return self.offsets[1:] - self.offsets[:-1]

    @cached_property
    def pixel_index(self) -> np.ndarray:
        """(T,) pixel of every sample."""
        return np.repeat(np.arange(self.pixel_count), self.counts)

    @property
    def has_aux(self) -> bool:
        return self.aux is not None and self.aux_offsets is not None and self.eps is not None


@dataclass
class EstimateStats:
    pixels: int = 0
    needs_redraw: int = 0  # pixels with an unbounded W cell (vor, vor_sn, fvor)
    empty_pixels: int = 0  # pixels with N = 0 (estimate 0)
    empty_filtered: int = 0  # fvor pixels with no cell inside W' (fell back to vor_sn)
    tessellation: TessellationStats = field(default_factory=TessellationStats)


@dataclass
class EstimateResult:
    """estimates: (P,) or (P, C), NaN where needs_redraw; needs_redraw: (P,) bool."""

    estimates: np.ndarray
    needs_redraw: np.ndarray
    stats: EstimateStats


def estimate(
    name: str, samples: PixelSamples, cells: dict[str, CellAreas] | None = None
) -> EstimateResult:
    """One estimate per pixel with estimator `name` (see the module docstring)."""
    return estimate_all([name], samples, cells)[name]


def estimate_all(
    names: Sequence[str], samples: PixelSamples, cells: dict[str, CellAreas] | None = None
) -> dict[str, EstimateResult]:
    """Several estimators on the same samples, computing each tessellation once.

    cells: tessellations already computed elsewhere, by kind ("sppp", "clipped", "periodic"),
    e.g. the device backend's SPPP cells (clrender.device_voronoi); the others are computed
    here with Qhull. A given "sppp" tessellation must carry inside-W' flags for fvor.
    """
    infos = [estimator_info(name) for name in names]
    _check_samples(samples, infos)
    given = dict(cells or {})
    computed = _tessellations(samples, infos, skip=set(given))
    tessellations = {**computed, **given}
    return {info.name: _ESTIMATE[info.name](samples, tessellations) for info in infos}


# ---------------------------------------------------------------------------------------------
# Input checks and tessellations


def _check_samples(samples: PixelSamples, infos: list[EstimatorInfo]) -> None:
    pos, val, off = samples.positions, samples.values, samples.offsets
    if pos.ndim != 2 or pos.shape[1] != 2:
        raise ParameterError(f"positions must have shape (T, 2), got {pos.shape}")
    if val.ndim not in (1, 2) or len(val) != len(pos):
        raise ParameterError(
            f"values must have shape (T,) or (T, C) with T = {len(pos)}, got {val.shape}"
        )
    _check_offsets("offsets", off, len(pos))
    if not np.isfinite(pos).all() or (np.abs(pos) > 0.5).any():
        raise ParameterError("sample positions must be finite and inside W = [-1/2, 1/2]^2")
    if not (np.isfinite(samples.intensity) and samples.intensity > 0):
        raise ParameterError(f"intensity n must be positive, got {samples.intensity!r}")
    for info in infos:
        if info.needs_aux and not samples.has_aux:
            raise ParameterError(
                f"estimator {info.name!r} needs SPPP auxiliary nuclei (aux, aux_offsets and "
                "eps, e.g. from the sppp sampler); use mc, cvor or pvor with other samplers"
            )
    if samples.has_aux and any(info.needs_aux for info in infos):
        aux = samples.aux
        if aux.ndim != 2 or aux.shape[1] != 2 or not np.isfinite(aux).all():
            raise ParameterError(f"aux must be a finite (A, 2) array, got shape {aux.shape}")
        _check_offsets("aux_offsets", samples.aux_offsets, len(aux))
        if len(samples.aux_offsets) != len(off):
            raise ParameterError("aux_offsets and offsets must describe the same pixels")
        if not (np.isfinite(samples.eps) and samples.eps >= 0):
            raise ParameterError(f"eps must be >= 0, got {samples.eps!r}")


def _check_offsets(name: str, offsets: np.ndarray, total: int) -> None:
    if (
        offsets.ndim != 1
        or len(offsets) < 1
        or offsets[0] != 0
        or offsets[-1] != total
        or (offsets[1:] < offsets[:-1]).any()
    ):
        raise ParameterError(f"{name} must rise from 0 to {total} (one more entry than pixels)")


def _tessellations(
    samples: PixelSamples, infos: list[EstimatorInfo], skip: set[str] = frozenset()
) -> dict[str, CellAreas]:
    kinds = {info.cells for info in infos} - set(skip)
    cells = {}
    if "sppp" in kinds:
        box = 0.5 + samples.eps if any(info.name == "fvor" for info in infos) else None
        cells["sppp"] = sppp_cells(
            samples.positions, samples.offsets, samples.aux, samples.aux_offsets, box
        )
    if "clipped" in kinds:
        cells["clipped"] = clipped_cells(samples.positions, samples.offsets)
    if "periodic" in kinds:
        cells["periodic"] = periodic_cells(samples.positions, samples.offsets)
    return cells


# ---------------------------------------------------------------------------------------------
# Estimators


def _pixel_sums(samples: PixelSamples, weights: np.ndarray) -> np.ndarray:
    """Per-pixel sums of (T,) or (T, C) weights -> (P,) or (P, C) (0 for empty pixels).
    Samples are grouped by pixel, so each pixel's sum is one segment of a reduceat (all
    channels in one pass over contiguous rows)."""
    sums = np.zeros((samples.pixel_count,) + weights.shape[1:], np.float64)
    occupied = samples.counts > 0
    if occupied.any():
        sums[occupied] = np.add.reduceat(weights, samples.offsets[:-1][occupied], axis=0)
    return sums


def _per_sample(column: np.ndarray, values: np.ndarray) -> np.ndarray:
    """A (T,) column broadcast against (T,) or (T, C) values."""
    return column if values.ndim == 1 else column[:, None]


def _per_pixel(column: np.ndarray, estimates: np.ndarray) -> np.ndarray:
    return column if estimates.ndim == 1 else column[:, None]


def _base_stats(samples: PixelSamples, tessellation: TessellationStats | None) -> EstimateStats:
    stats = EstimateStats(pixels=samples.pixel_count, empty_pixels=int((samples.counts == 0).sum()))
    if tessellation is not None:
        stats.tessellation = tessellation
    return stats


def _no_redraw(samples: PixelSamples) -> np.ndarray:
    return np.zeros(samples.pixel_count, bool)


def _mc(samples: PixelSamples, cells) -> EstimateResult:
    sums = _pixel_sums(samples, samples.values)
    return EstimateResult(sums / samples.intensity, _no_redraw(samples), _base_stats(samples, None))


def _mc_n(samples: PixelSamples, cells) -> EstimateResult:
    sums = _pixel_sums(samples, samples.values)
    counts = samples.counts.astype(np.float64)
    means = sums / _per_pixel(np.maximum(counts, 1.0), sums)
    return EstimateResult(means, _no_redraw(samples), _base_stats(samples, None))


def _weighted(samples: PixelSamples, areas: np.ndarray) -> np.ndarray:
    """sum f v per pixel."""
    return _pixel_sums(samples, samples.values * _per_sample(areas, samples.values))


def _invalid_pixels(samples: PixelSamples, bounded: np.ndarray) -> np.ndarray:
    invalid = np.zeros(samples.pixel_count, bool)
    invalid[samples.pixel_index[~bounded]] = True
    return invalid


def _redraw_result(samples, estimates, cell_areas: CellAreas) -> EstimateResult:
    redraw = _invalid_pixels(samples, cell_areas.bounded)
    estimates = np.where(_per_pixel(redraw, estimates), np.nan, estimates)
    stats = _base_stats(samples, cell_areas.stats)
    stats.needs_redraw = int(redraw.sum())
    return EstimateResult(estimates, redraw, stats)


@dataclass
class SpppSums:
    """Per-pixel sums behind vor, vor_sn and fvor: over the pixel's W nuclei, sum v and
    sum f v; over those whose cell lies inside W' (fvor's kept nuclei), the same. Computed on
    the host (sppp_sums) or on the device (clrender.device_voronoi.device_sppp_sums)."""

    area: np.ndarray  # (P,)
    weighted: np.ndarray  # (P,) or (P, C)
    kept_area: np.ndarray  # (P,)
    kept_weighted: np.ndarray  # (P,) or (P, C)


def sppp_sums(samples: PixelSamples, cells: CellAreas, kept: bool = True) -> SpppSums:
    """The sums of the given SPPP cells; the kept ones (fvor's) only if asked for and the cells
    carry inside-W' flags, else NaN."""
    products = samples.values * _per_sample(cells.areas, samples.values)
    if not kept or cells.inside_box is None:
        kept_area = np.full(samples.pixel_count, np.nan)
        kept_weighted = np.full((samples.pixel_count,) + products.shape[1:], np.nan)
    else:
        # where, not a product with 0: a dropped nucleus's value is ignored even if infinite
        kept_area = _pixel_sums(samples, np.where(cells.inside_box, cells.areas, 0.0))
        kept_weighted = _pixel_sums(
            samples, np.where(_per_sample(cells.inside_box, products), products, 0.0)
        )
    return SpppSums(
        _pixel_sums(samples, cells.areas), _pixel_sums(samples, products), kept_area, kept_weighted
    )


def sppp_estimates(name: str, sums: SpppSums, counts: np.ndarray) -> np.ndarray:
    """vor, vor_sn or fvor of every pixel from its sums (redraws not marked here):
    vor = sum f v; vor_sn = sum f v / sum v (0 when sum v = 0); fvor = the same ratio over the
    kept nuclei, or vor_sn where a pixel has nuclei but none kept."""
    if name == "vor":
        return sums.weighted
    ratio = _ratio(sums.weighted, sums.area)
    if name == "vor_sn":
        return ratio
    if name != "fvor":
        raise ParameterError(f"{name!r} is not an estimator of SPPP cell sums")
    use_fallback = _fvor_fallback(sums, counts)
    return np.where(
        _per_pixel(use_fallback, ratio), ratio, _ratio(sums.kept_weighted, sums.kept_area)
    )


def _ratio(weighted: np.ndarray, area: np.ndarray) -> np.ndarray:
    """weighted / area per pixel, 0 where area == 0."""
    empty = area == 0
    return np.where(
        _per_pixel(empty, weighted),
        0.0,
        weighted / _per_pixel(np.where(empty, 1.0, area), weighted),
    )


def _fvor_fallback(sums: SpppSums, counts: np.ndarray) -> np.ndarray:
    """Pixels with nuclei but no kept nucleus (fvor gives their vor_sn)."""
    return (sums.kept_area == 0) & (counts > 0)


def _sppp_estimator(name: str, samples: PixelSamples, cells) -> EstimateResult:
    sppp = cells["sppp"]
    sums = sppp_sums(samples, sppp, kept=name == "fvor")
    result = _redraw_result(samples, sppp_estimates(name, sums, samples.counts), sppp)
    if name == "fvor":
        fallback = _fvor_fallback(sums, samples.counts)
        result.stats.empty_filtered = int((fallback & ~result.needs_redraw).sum())
    return result


def _vor(samples: PixelSamples, cells) -> EstimateResult:
    return _sppp_estimator("vor", samples, cells)


def _vor_sn(samples: PixelSamples, cells) -> EstimateResult:
    return _sppp_estimator("vor_sn", samples, cells)


def _fvor(samples: PixelSamples, cells) -> EstimateResult:
    return _sppp_estimator("fvor", samples, cells)


def _cvor(samples: PixelSamples, cells) -> EstimateResult:
    clipped = cells["clipped"]
    return EstimateResult(
        _weighted(samples, clipped.areas), _no_redraw(samples), _base_stats(samples, clipped.stats)
    )


def _pvor(samples: PixelSamples, cells) -> EstimateResult:
    periodic = cells["periodic"]
    return EstimateResult(
        _weighted(samples, periodic.areas),
        _no_redraw(samples),
        _base_stats(samples, periodic.stats),
    )


_ESTIMATE = {
    "mc": _mc,
    "mc_n": _mc_n,
    "vor": _vor,
    "vor_sn": _vor_sn,
    "fvor": _fvor,
    "cvor": _cvor,
    "pvor": _pvor,
}
