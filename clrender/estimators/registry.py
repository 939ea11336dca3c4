"""The estimator registry: every pixel estimator, per-pixel and image-level, in one table.

An estimator is a formula over per-pixel sums (PixelSums) of one tessellation's cells:

| name    | estimate of pixel p (sums over its N traced nuclei x in W)     | cells    | needs    |
|---------|----------------------------------------------------------------|----------|----------|
| mc      | sum f(x) / n, n the intensity (unbiased for Poisson N)          | none     | any      |
| mc_n    | sum f(x) / N, 0 when N = 0 (the conditional form)               | none     | any      |
| vor     | E_V = sum f(x) v(x), cells of W + aux nuclei, not normalised    | sppp     | aux      |
| vor_sn  | sum f(x) v(x) / sum v(x), same cells (self-normalised)          | sppp     | aux      |
| fvor    | E_F: like vor_sn over the nuclei whose cell lies inside W'      | sppp     | aux      |
| cvor    | E_C = sum f(x) |C(x) cap W|, cells of the W nuclei only         | clipped  | any      |
| pvor    | sum f(x) v_torus(x), cells on the torus W                       | periodic | any      |
| ivor    | sum f(x) |C(x)|, one tessellation of every pixel's nuclei      | image    | Poisson  |
| ivor_sn | the same divided by sum |C(x)| over the pixel's nuclei          | image    | Poisson  |

Conventions and choices:
- mc divides by the intensity n, which is unbiased when N ~ Poisson(n) (and equals the sample
  mean for fixed-count samplers, where N = n). mc_n divides by N.
- vor is the paper's E_V, *not* normalised; vor_sn (self-normalised) is what the authors'
  renderer computes and what the paper's measured "vor" column matches. They are different
  estimators and are reported under different names.
- A traced nucleus with an unbounded cell (on the convex hull of W + aux nuclei) rejects its
  pixel: the estimate is NaN and needs_redraw is set; clrender.estimators.redraw redraws it.
- fvor with no nucleus whose cell lies in W' falls back to vor_sn for that pixel (counted in
  stats.empty_filtered).
- A pixel with N = 0 estimates 0 with every estimator (counted in stats.empty_pixels).
- A non-finite value (NaN, +-Inf) makes its pixel's estimate non-finite (fvor: only if the
  nucleus is kept); other pixels are unaffected.
- pvor: W as a torus; exactly unbiased for N i.i.d. uniform points (a fixed N >= 1), no aux
  nuclei, no rejection. Over a Poisson count its mean is (1 - e^-n) times the pixel's value
  (Mecke's formula: the torus cell of an added point has mean area (1 - e^-n) / n), exactly
  the pixels with N = 0, which estimate 0: a bias only at small n (pairing_advice warns).
  The same holds for every count-normalised estimator (Estimator.count_normalised: mc_n,
  vor_sn, fvor, cvor, pvor, ivor_sn; the self-normalised ones add their ratio bias), while mc
  and ivor stay unbiased over a Poisson count. vor would be too over a process on the whole
  plane; the paper's truncated construction (a fixed count of auxiliary nuclei in the strip,
  none beyond, rejection) biases it by +4 % at n = 1, -0.6 % at n = 2, +0.2 % at n = 16 and
  +0.03 % at n = 64 (bench/vor_bias.py; README, Pixel estimators).
- ivor, ivor_sn: the pixels' nuclei together form one Poisson process of intensity n on the
  image plane; neighbours' nuclei shape the cells (clrender.estimators.image).

Adding an estimator: one Estimator entry below and its formula (a function of PixelSums); the
pipeline, the command line and the redraw driver ask the entry, never the name.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from clrender.errors import ParameterError

# The tessellations an estimator can weight its samples with (clrender.estimators.pixel and
# .image compute them): none, the SPPP cells of W + auxiliary nuclei, the W nuclei's cells
# clipped to W, cells on the torus W, or one tessellation of the whole image plane.
CELL_KINDS = ("none", "sppp", "clipped", "periodic", "image")


@dataclass
class PixelSums:
    """Per-pixel sums an estimator's formula reads: over pixel p's N traced nuclei x, sum f(x)
    (value), sum v(x) (area) and sum f(x) v(x) (weighted), v the cell area of the estimator's
    tessellation; kept_*: the same over the nuclei whose cell lies inside W' (fvor); square:
    sum f(x)^2 (the device sums form it, for the per-pixel variance layer). Sums are (P,) or
    (P, C); those a tessellation does not form are None."""

    counts: np.ndarray  # (P,) N, traced nuclei per pixel
    n: float  # the sampler's intensity
    value: np.ndarray | None = None
    area: np.ndarray | None = None
    weighted: np.ndarray | None = None
    kept_area: np.ndarray | None = None
    kept_weighted: np.ndarray | None = None
    square: np.ndarray | None = None


def per_pixel(column: np.ndarray, like: np.ndarray) -> np.ndarray:
    """A (P,) column broadcast against (P,) or (P, C) sums."""
    return column if like.ndim == 1 else column[:, None]


def ratio(weighted: np.ndarray, area: np.ndarray) -> np.ndarray:
    """weighted / area per pixel, 0 where area == 0."""
    empty = area == 0
    return np.where(
        per_pixel(empty, weighted), 0.0, weighted / per_pixel(np.where(empty, 1.0, area), weighted)
    )


def kept_fallback(sums: PixelSums) -> np.ndarray:
    """Pixels with nuclei but no kept nucleus (fvor gives their vor_sn)."""
    return (sums.kept_area == 0) & (sums.counts > 0)


# --- formulas --------------------------------------------------------------------------------


def mean_over_intensity(sums: PixelSums) -> np.ndarray:
    return sums.value / sums.n


def mean_over_count(sums: PixelSums) -> np.ndarray:
    counts = sums.counts.astype(np.float64)
    return sums.value / per_pixel(np.maximum(counts, 1.0), sums.value)


def weighted_sum(sums: PixelSums) -> np.ndarray:
    return sums.weighted


def self_normalised(sums: PixelSums) -> np.ndarray:
    return ratio(sums.weighted, sums.area)


def filtered_self_normalised(sums: PixelSums) -> np.ndarray:
    everything = ratio(sums.weighted, sums.area)
    return np.where(
        per_pixel(kept_fallback(sums), everything),
        everything,
        ratio(sums.kept_weighted, sums.kept_area),
    )


# --- the registry ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Estimator:
    """One pixel estimator: what it is, what it needs and how it is computed."""

    name: str
    description: str  # one line, shown in errors and help
    formula: Callable[[PixelSums], np.ndarray]
    cells: str = "none"  # one of CELL_KINDS
    needs_aux: bool = False  # SPPP auxiliary nuclei (and eps)
    needs_poisson: bool = False  # Poisson sample counts (the whole image is one process)
    kept_cells: bool = False  # sums also over the nuclei whose cell lies inside W'
    device_sums: bool = False  # the device can form its cells and sums (kernels/voronoi_*.cl)
    # Its weights sum to 1 over a pixel's drawn samples, and a pixel that draws none estimates
    # 0: over a Poisson count (the SPPP samplers) its mean is (1 - e^-n) times the value
    # (exactly for mc_n and pvor; with the self-normalised ratio's own bias for the others)
    count_normalised: bool = False

    def __post_init__(self) -> None:
        device_kinds = ("sppp", "periodic", "clipped")  # device_cells.CELL_KINDS
        if self.cells not in CELL_KINDS or (self.device_sums and self.cells not in device_kinds):
            raise ValueError(f"estimator {self.name!r}: cells {self.cells!r} / device_sums")

    @property
    def image_level(self) -> bool:
        """Neighbouring pixels' nuclei shape the cells (clrender.estimators.image)."""
        return self.cells == "image"

    @property
    def needs_sppp(self) -> bool:
        return self.needs_aux or self.needs_poisson


ESTIMATORS: dict[str, Estimator] = {
    entry.name: entry
    for entry in [
        Estimator(
            "mc",
            "Monte Carlo: sum of values / intensity n (unbiased for Poisson N)",
            mean_over_intensity,
        ),
        Estimator(
            "mc_n",
            "Monte Carlo, conditional form: mean of the N values (0 if N = 0)",
            mean_over_count,
            count_normalised=True,
        ),
        Estimator(
            "vor",
            "Voronoi E_V: sum f(x) area(cell(x)), cells of W + auxiliary nuclei, not normalised",
            weighted_sum,
            cells="sppp",
            needs_aux=True,
            device_sums=True,
        ),
        Estimator(
            "vor_sn",
            "self-normalised Voronoi: sum f v / sum v over the W nuclei "
            "(the authors' renderer's 'vor')",
            self_normalised,
            cells="sppp",
            needs_aux=True,
            device_sums=True,
            count_normalised=True,
        ),
        Estimator(
            "fvor",
            "filtered Voronoi E_F: self-normalised over the nuclei whose cell lies inside W'",
            filtered_self_normalised,
            cells="sppp",
            needs_aux=True,
            kept_cells=True,
            device_sums=True,
            count_normalised=True,
        ),
        Estimator(
            "cvor",
            "clipped Voronoi E_C: cells of the W nuclei alone clipped to W (biased near edges)",
            weighted_sum,
            cells="clipped",
            device_sums=True,
            count_normalised=True,
        ),
        Estimator(
            "pvor",
            "periodic Voronoi: cells on the torus W (unbiased for a fixed number of points; over "
            "a Poisson count (1 - e^-n) times the value), no auxiliary nuclei, no rejection",
            weighted_sum,
            cells="periodic",
            device_sums=True,
            count_normalised=True,
        ),
        Estimator(
            "ivor",
            "image-level Voronoi: one tessellation of all pixels' nuclei, sum f v over the "
            "pixel's own nuclei (unbiased, no strip, no rejection)",
            weighted_sum,
            cells="image",
            needs_poisson=True,
        ),
        Estimator(
            "ivor_sn",
            "image-level Voronoi, self-normalised per pixel (lower variance, O(1/n) ratio bias)",
            self_normalised,
            cells="image",
            needs_poisson=True,
            count_normalised=True,
        ),
    ]
}


def estimator_info(estimator: str | Estimator) -> Estimator:
    """The registry entry of a name (an entry is returned as it is); ParameterError listing the
    accepted names otherwise. The one place an estimator name is validated."""
    if isinstance(estimator, Estimator):
        return estimator
    try:
        return ESTIMATORS[estimator]
    except (KeyError, TypeError):
        raise ParameterError(
            f"unknown estimator {estimator!r}; accepted: {', '.join(ESTIMATORS)}"
        ) from None


def check_compatible(estimator: str | Estimator, sampler: str) -> Estimator:
    """The entry, or a one-line error if it needs what only the SPPP samplers draw (an unknown
    sampler name is a one-line error too)."""
    from clrender.sampling import SAMPLERS, sampler_kind

    entry = estimator_info(estimator)
    if entry.needs_sppp and not sampler_kind(sampler).is_sppp:
        what = "auxiliary nuclei" if entry.needs_aux else "Poisson sample counts"
        anywhere = ", ".join(name for name, other in ESTIMATORS.items() if not other.needs_sppp)
        sppp_samplers = " or ".join(name for name, kind in SAMPLERS.items() if kind.is_sppp)
        raise ParameterError(
            f"estimator {entry.name!r} needs the {what} of an SPPP sampler, and the "
            f"{sampler!r} sampler draws none: use --sampler {sppp_samplers}, or an estimator "
            f"that works with any sampler ({anywhere})"
        )
    return entry


# What a pixel still rejected after the last redraw gets (clrender.estimators.redraw).
MC = ESTIMATORS["mc"]


class EstimatorWarning(UserWarning):
    """An estimator and sampler pair that works but is known to be a poor choice."""


# Below this empty-pixel probability e^-n the count-normalised estimators' bias over a Poisson
# count goes unmentioned (n >= 7)
EMPTY_PIXEL_ADVICE = 1e-3


def pairing_advice(estimator: str | Estimator, sampler: str, n: int | None = None) -> str | None:
    """One line saying why the pair (at n samples per pixel, when given) is a poor choice and
    what to use instead, or None."""
    from clrender.sampling import sampler_kind

    entry = estimator_info(estimator)
    empty = math.exp(-n) if n is not None else 0.0
    poisson = sampler_kind(sampler).is_sppp
    if entry.count_normalised and poisson and empty >= EMPTY_PIXEL_ADVICE:
        exactly = "" if entry.name in ("mc_n", "pvor") else "about "
        return (
            f"{entry.name} over the {sampler} sampler at n = {n}: a pixel draws no sample with "
            f"probability e^-n = {empty:.2g} and then estimates 0, so {entry.name}'s mean is "
            f"{exactly}(1 - e^-n) times the pixel's value; unbiased at this n: mc over "
            f"{sampler}"
            + (", ivor" if sampler == "sppp" else "")
            + ", or mc over --sampler sobol (vor is off by a few percent at n = 1)"
        )
    if entry.name == "mc" and sampler_kind(sampler).is_sppp:
        return (
            f"mc over the {sampler} sampler divides by the intensity n while each pixel draws a "
            "Poisson number N of samples, so the count's own variance adds to every pixel "
            "(far noisier than mc over fixed counts): use "
            + (
                f"--estimator mc_n or vor_sn with {sampler}, or "
                if empty < EMPTY_PIXEL_ADVICE
                else ""  # at small n those lose the empty pixels (above)
            )
            + "mc with --sampler sobol"
        )
    return None
