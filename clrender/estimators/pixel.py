"""Per-pixel estimation: each pixel's integral over W = [-1/2, 1/2]^2 from its own samples.

estimate / estimate_all take a batch of pixels' samples (clrender.samples.SampleSets) and the
values of their traced samples ((T,) or (T, C)), form each tessellation the requested
estimators need once (Qhull, clrender.estimators.qhull_cells, unless given, e.g. the device's
cells), reduce them to per-pixel sums and apply each estimator's formula (the registry,
clrender.estimators.registry, says which cells and which formula). |W| = 1, so an estimate is
also the pixel's mean value. Image-level estimators (ivor, ivor_sn) tessellate neighbouring
pixels together: clrender.estimators.image.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from clrender.errors import ParameterError
from clrender.estimators.qhull_cells import (
    CellAreas,
    TessellationStats,
    clipped_cells,
    periodic_cells,
    sppp_cells,
)
from clrender.estimators.registry import (
    ESTIMATORS,
    Estimator,
    PixelSums,
    estimator_info,
    kept_fallback,
    per_pixel,
)
from clrender.samples import SampleSets

# The per-pixel tessellations, by the registry's cell kind (sppp is handled with its box).
_GHOST_CELLS = {"clipped": clipped_cells, "periodic": periodic_cells}


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
    name: str | Estimator,
    samples: SampleSets,
    values: np.ndarray,
    cells: dict[str, CellAreas] | None = None,
) -> EstimateResult:
    """One estimate per pixel with one estimator (a name or a registry entry)."""
    entry = estimator_info(name)
    return estimate_all([entry], samples, values, cells)[entry.name]


def estimate_all(
    names: Sequence[str | Estimator],
    samples: SampleSets,
    values: np.ndarray,
    cells: dict[str, CellAreas] | None = None,
) -> dict[str, EstimateResult]:
    """Several per-pixel estimators on the same samples, computing each tessellation once.

    cells: tessellations already computed elsewhere, by kind ("sppp", "clipped", "periodic"),
    e.g. the device backend's SPPP cells (clrender.estimators.device_cells); the others are
    computed here with Qhull. A given "sppp" tessellation must carry inside-W' flags for fvor.
    """
    entries = [estimator_info(name) for name in names]
    values = np.asarray(values, np.float64)
    _check_samples(samples, values, entries)
    given = dict(cells or {})
    tessellations = {**_tessellations(samples, entries, skip=set(given)), **given}
    kept = any(entry.kept_cells for entry in entries)
    kinds = {entry.cells for entry in entries}
    sums = {kind: cell_sums(samples, values, tessellations.get(kind), kept) for kind in kinds}
    return {
        entry.name: _result(entry, samples, sums[entry.cells], tessellations.get(entry.cells))
        for entry in entries
    }


def cell_sums(
    samples: SampleSets, values: np.ndarray, cells: CellAreas | None, kept: bool = False
) -> PixelSums:
    """Each pixel's sums: of the values alone without cells; else sum v and sum f v, and with
    `kept` (and cells carrying inside-W' flags) the same over the kept nuclei (NaN otherwise)."""
    sums = PixelSums(samples.counts, samples.n)
    if cells is None:
        sums.value = pixel_sums(samples, values)
        return sums
    products = values * per_pixel(cells.areas, values)
    sums.area = pixel_sums(samples, cells.areas)
    sums.weighted = pixel_sums(samples, products)
    if not kept or cells.inside_box is None:
        sums.kept_area = np.full(samples.pixel_count, np.nan)
        sums.kept_weighted = np.full((samples.pixel_count,) + products.shape[1:], np.nan)
    else:
        # where, not a product with 0: a dropped nucleus's value is ignored even if infinite
        sums.kept_area = pixel_sums(samples, np.where(cells.inside_box, cells.areas, 0.0))
        sums.kept_weighted = pixel_sums(
            samples, np.where(per_pixel(cells.inside_box, products), products, 0.0)
        )
    return sums


# ---------------------------------------------------------------------------------------------
# Input checks and tessellations


def _check_samples(samples: SampleSets, values: np.ndarray, entries: list[Estimator]) -> None:
    pos, off = samples.traced, samples.offsets
    for entry in entries:
        if entry.image_level:
            raise ParameterError(
                f"estimator {entry.name!r} tessellates the whole image: use "
                "clrender.estimators.image (estimate_image) or a render"
            )
    if pos.ndim != 2 or pos.shape[1] != 2:
        raise ParameterError(f"positions must have shape (T, 2), got {pos.shape}")
    if values.ndim not in (1, 2) or len(values) != len(pos):
        raise ParameterError(
            f"values must have shape (T,) or (T, C) with T = {len(pos)}, got {values.shape}"
        )
    _check_offsets("offsets", off, len(pos))
    if not np.isfinite(pos).all() or (np.abs(pos) > 0.5).any():
        raise ParameterError("sample positions must be finite and inside W = [-1/2, 1/2]^2")
    if not (np.isfinite(samples.n) and samples.n > 0):
        raise ParameterError(f"intensity n must be positive, got {samples.n!r}")
    for entry in entries:
        if entry.needs_aux and not samples.has_aux:
            raise ParameterError(
                f"estimator {entry.name!r} needs SPPP auxiliary nuclei (aux, aux_offsets and "
                f"eps, e.g. from the sppp sampler); use {_without_aux()} with other samplers"
            )
    if samples.has_aux and any(entry.needs_aux for entry in entries):
        aux = samples.aux
        if aux.ndim != 2 or aux.shape[1] != 2 or not np.isfinite(aux).all():
            raise ParameterError(f"aux must be a finite (A, 2) array, got shape {aux.shape}")
        _check_offsets("aux_offsets", samples.aux_offsets, len(aux))
        if len(samples.aux_offsets) != len(off):
            raise ParameterError("aux_offsets and offsets must describe the same pixels")
        if not (np.isfinite(samples.eps) and samples.eps >= 0):
            raise ParameterError(f"eps must be >= 0, got {samples.eps!r}")


def _without_aux() -> str:
    names = [e.name for e in ESTIMATORS.values() if not e.needs_sppp]
    return ", ".join(names[:-1]) + " or " + names[-1]


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
    samples: SampleSets, entries: list[Estimator], skip: set[str] = frozenset()
) -> dict[str, CellAreas]:
    kinds = {entry.cells for entry in entries} - {"none"} - set(skip)
    cells = {}
    if "sppp" in kinds:
        box = 0.5 + samples.eps if any(entry.kept_cells for entry in entries) else None
        cells["sppp"] = sppp_cells(
            samples.traced, samples.offsets, samples.aux, samples.aux_offsets, box
        )
    for kind in kinds & set(_GHOST_CELLS):
        cells[kind] = _GHOST_CELLS[kind](samples.traced, samples.offsets)
    return cells


# ---------------------------------------------------------------------------------------------
# Sums and results


def pixel_sums(samples: SampleSets, weights: np.ndarray) -> np.ndarray:
    """Per-pixel sums of (T,) or (T, C) weights -> (P,) or (P, C) (0 for empty pixels).
    Samples are grouped by pixel, so each pixel's sum is one segment of a reduceat (all
    channels in one pass over contiguous rows)."""
    sums = np.zeros((samples.pixel_count,) + weights.shape[1:], np.float64)
    occupied = samples.counts > 0
    if occupied.any():
        sums[occupied] = np.add.reduceat(weights, samples.offsets[:-1][occupied], axis=0)
    return sums


def _result(
    entry: Estimator, samples: SampleSets, sums: PixelSums, cells: CellAreas | None
) -> EstimateResult:
    """The entry's formula on the sums; a pixel with an unbounded cell is rejected (NaN)."""
    estimates = entry.formula(sums)
    stats = EstimateStats(pixels=samples.pixel_count, empty_pixels=int((sums.counts == 0).sum()))
    redraw = np.zeros(samples.pixel_count, bool)
    if cells is not None:
        stats.tessellation = cells.stats
        redraw[samples.pixel_index[~cells.bounded]] = True
        estimates = np.where(per_pixel(redraw, estimates), np.nan, estimates)
        stats.needs_redraw = int(redraw.sum())
    if entry.kept_cells:
        stats.empty_filtered = int((kept_fallback(sums) & ~redraw).sum())
    return EstimateResult(estimates, redraw, stats)
