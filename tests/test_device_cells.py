"""Device Voronoi cells (clrender.estimators.device_cells, kernels/voronoi_cells.cl) against the
host reference (clrender.estimators.qhull_cells.sppp_cells, SciPy Qhull) and against exact
geometry.

Inputs are rounded to float32 first (the device's format), so both sides see one point set.
Tolerances: precision "auto" (mixed on PoCL: final vertices in float64) must match Qhull to
1e-9 relative; "single" (forced here, and what "auto" is on a device without cl_khr_fp64 or with
CLRENDER_NO_FP64 set) to 1e-4 relative (measured 2e-5 at worst, typical 1e-6). Flags must be
identical in every precision.
"""

from __future__ import annotations

import contextlib
import hashlib
import shutil
import sys
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

from clrender.errors import ParameterError
from clrender.estimators import device_cells, estimate_all
from clrender.estimators import pixel as pixel_estimators
from clrender.estimators.device_cells import (
    device_sppp_cells,
    device_sppp_cells_from_arrays,
    sppp_cells_backend,
)
from clrender.estimators.pixel import cell_sums
from clrender.estimators.qhull_cells import sppp_cells
from clrender.runtime import has_fp64, kernels_dir, launch_global_size
from clrender.samples import SampleSets
from clrender.sampling import generate_sample_sets, make_sampler
from clrender.sppp import draw_sppp

AREA_RTOL = 1e-9
SINGLE_RTOL = 1e-4
# Single precision (no cl_khr_fp64, or forced; measured on PoCL with CLRENDER_NO_FP64): a
# pixel's cell areas sum to 1 within SINGLE_TILE_ATOL (measured 7.5e-7), and per-pixel sums and
# estimates, float32 sums of float32 areas, within SINGLE_SUMS_RTOL of the host's (6e-7)
SINGLE_TILE_ATOL = 1e-5
SINGLE_SUMS_RTOL = 1e-5


def rounded(array: np.ndarray) -> np.ndarray:
    return np.asarray(array, np.float32).astype(np.float64).reshape(-1, 2)


def offsets_of(counts) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


def both(runtime, traced, offsets, aux, aux_offsets, box, precision="auto"):
    """(device cells, host cells) of one float32-rounded batch."""
    traced, aux = rounded(traced), rounded(aux)
    host = sppp_cells(traced, offsets, aux, aux_offsets, box)
    device = device_sppp_cells_from_arrays(
        runtime, traced, offsets, aux, aux_offsets, box, precision
    )
    return device, host


@pytest.fixture
def area_rtol(single_precision):
    """The tolerance of precision "auto" on this device (single without cl_khr_fp64)."""
    return SINGLE_RTOL if single_precision else AREA_RTOL


def assert_same_cells(device, host, rtol):
    np.testing.assert_array_equal(device.bounded, host.bounded)
    np.testing.assert_allclose(device.areas, host.areas, rtol=rtol, atol=0, equal_nan=True)
    if host.inside_box is not None:
        np.testing.assert_array_equal(device.inside_box, host.inside_box)


def cell_status(runtime, traced, aux, box=None):
    """The device's status byte of each traced cell of one pixel (float32-rounded nuclei)."""
    flat = np.concatenate([rounded(traced), rounded(aux)]).astype(np.float32)
    layout = device_cells.CellLayout(
        runtime.upload(flat),
        offsets_of([len(rounded(traced))]),
        offsets_of([len(rounded(aux))]),
        max(float(np.abs(flat).max()), 0.5),
        device_cells.grid_side(len(flat), 1),
        float(np.abs(rounded(traced)).max()),
    )
    defines, real = device_cells.precision_setup(runtime, "auto")
    return device_cells.launch_cell_kernels(runtime, layout, box, defines, real)[1]


def sppp_batch(n, pixels, seed, eps=None):
    batch = draw_sppp(np.random.default_rng(seed), n, pixels, eps=eps)
    return batch, float(np.float32(0.5 + batch.eps))


# 1. Random SPPP pixels: areas, bounded and inside-W' flags equal Qhull's
@pytest.mark.parametrize(
    "n, pixels", [(1, 3000), (4, 3000), (16, 1500), (64, 600), (256, 150), (1024, 40)]
)
def test_areas_and_flags_match_qhull(runtime, area_rtol, n, pixels):
    batch, box = sppp_batch(n, pixels, seed=100 + n)
    device, host = both(runtime, batch.traced, batch.offsets, batch.aux, batch.aux_offsets, box)
    assert_same_cells(device, host, area_rtol)
    assert device.bounded.mean() > 0.99


# 1b. The inside flag against a box that many cells cross (W itself)
@pytest.mark.parametrize("n", [4, 64, 256])
def test_inside_flags_match_qhull(runtime, area_rtol, n):
    batch, _ = sppp_batch(n, 200, seed=n)
    device, host = both(runtime, batch.traced, batch.offsets, batch.aux, batch.aux_offsets, 0.5)
    assert_same_cells(device, host, area_rtol)
    assert 0.05 < device.inside_box.mean() < 0.95


# 2. Float32 geometry throughout (for devices without cl_khr_fp64) stays within 1e-4
def test_single_precision_close_to_qhull(runtime):
    batch, box = sppp_batch(64, 400, seed=7)
    device, host = both(
        runtime, batch.traced, batch.offsets, batch.aux, batch.aux_offsets, box, precision="single"
    )
    assert_same_cells(device, host, rtol=SINGLE_RTOL)
    ok = host.bounded
    assert np.median(np.abs(device.areas[ok] / host.areas[ok] - 1)) < 1e-6


# 2b. Float64 throughout (precision "double": the walk over lanes of doubles) matches Qhull
@pytest.mark.parametrize("n", [16, 256])
def test_double_precision_matches_qhull(runtime, n):
    if not has_fp64(runtime.device):
        pytest.skip("no cl_khr_fp64 on this device")
    batch, box = sppp_batch(n, 3000 // n, seed=11 + n)
    device, host = both(
        runtime, batch.traced, batch.offsets, batch.aux, batch.aux_offsets, box, precision="double"
    )
    assert_same_cells(device, host, rtol=AREA_RTOL)
    assert device.stats.walked_cells > 0.95 * len(device.areas)


# 3. Mirror frame: with every nucleus mirrored across the four edges of W as auxiliary nuclei,
# the W cells are the cells clipped to W, so they tile W exactly (no Qhull involved)
@pytest.mark.parametrize("n", [1, 16, 256])
def test_mirror_frame_cells_tile_the_pixel(runtime, single_precision, n):
    rng = np.random.default_rng(n)
    counts = rng.poisson(n, 300)
    counts[0] = 1
    offsets = offsets_of(counts)
    # Dyadic coordinates (multiples of 2^-20) keep the mirrors exact in float32
    traced = rng.integers(0, 2**20, (offsets[-1], 2)) / 2**20 - 0.5
    x, y = traced[:, 0], traced[:, 1]
    mirrors = np.stack(
        [
            np.column_stack([1 - x, y]),
            np.column_stack([-1 - x, y]),
            np.column_stack([x, 1 - y]),
            np.column_stack([x, -1 - y]),
        ],
        axis=1,
    )
    aux = mirrors.reshape(-1, 2)  # pixel by pixel, since traced is
    cells = device_sppp_cells_from_arrays(runtime, traced, offsets, aux, offsets * 4)
    assert cells.bounded.all()
    pixel = np.repeat(np.arange(len(counts)), counts)
    sums = np.bincount(pixel, cells.areas, len(counts))
    atol = SINGLE_TILE_ATOL if single_precision else 1e-12
    np.testing.assert_allclose(sums[counts > 0], 1.0, rtol=0, atol=atol)


# 4. A square lattice (cocircular vertices everywhere): every cell is the lattice square
def test_lattice_cells_are_squares(runtime):
    k = 8
    h = 1.0 / k
    centres = (np.arange(k) + 0.5) * h - 0.5
    grid = np.array([(cx, cy) for cy in centres for cx in centres])
    ring = (np.arange(-1, k + 1) + 0.5) * h - 0.5
    aux = np.array([(cx, cy) for cy in ring for cx in ring if max(abs(cx), abs(cy)) > 0.5])
    offsets, aux_offsets = offsets_of([len(grid)]), offsets_of([len(aux)])
    device, host = both(runtime, grid, offsets, aux, aux_offsets, 0.5 + h)
    assert device.bounded.all()
    np.testing.assert_allclose(device.areas, h * h, rtol=1e-6)
    assert_same_cells(device, host, rtol=1e-6)
    # Four cells meet at every vertex: the two walks round a cell may take different
    # zero-length edges there and miss each other; the one-way walk then decides the cell
    status = cell_status(runtime, grid, aux, 0.5 + h)
    assert ((status & device_cells.STATUS_WALKED) != 0).all()
    assert ((status & device_cells.STATUS_WALKED_ONE_WAY) != 0).any()


# 4a. One nucleus among k neighbours on a circle (a regular k-gon cell): the two walks round
# the cell meet at an edge they both find (even k) or at an edge the clockwise walk found first
# (odd k), without the one-way walk; the area is the k-gon's, k (r / 2)^2 tan(pi / k)
@pytest.mark.parametrize("k", range(3, 11))
def test_walks_both_ways_meet_on_odd_and_even_cells(runtime, area_rtol, k):
    r = 0.2
    angles = 2 * np.pi * np.arange(k) / k + 0.1
    ring = r * np.column_stack([np.cos(angles), np.sin(angles)])
    centre = np.zeros((1, 2))
    status = cell_status(runtime, centre, ring)
    bits = device_cells.STATUS_BOUNDED | device_cells.STATUS_WALKED
    assert status[0] & (bits | device_cells.STATUS_WALKED_ONE_WAY) == bits
    device, host = both(runtime, centre, offsets_of([1]), ring, offsets_of([k]), None)
    assert_same_cells(device, host, area_rtol)
    np.testing.assert_allclose(device.areas[0], k * (r / 2) ** 2 * np.tan(np.pi / k), rtol=1e-6)


# 4b. The walk decides almost every cell of random pixels (the clipping search, which gives the
# same areas, is only for the rare cells it cannot): guards the kernel's fast path, whose loss
# no area comparison would show. Measured 98.6 % at n = 256 and 98.9 % at n = 4096.
@pytest.mark.parametrize("n, pixels", [(256, 64), (4096, 4)])
def test_walk_decides_most_cells(runtime, n, pixels):
    config = make_sampler("sppp", n)
    sets = generate_sample_sets(runtime, config, 5, np.arange(pixels, dtype=np.uint32))
    cells = device_sppp_cells(runtime, sets, 0.5 + config.eps)
    assert cells.stats.walked_cells >= 0.95 * len(cells.areas)


# 5. Tiny eps: many W nuclei on the hull. Flags equal Qhull's, and the device decides the
# unbounded cells itself (the host only redoes pixels with a bounded cell beyond the start box)
@pytest.mark.parametrize("n", [16, 64])
def test_forced_unbounded_cells_flagged_like_qhull(runtime, area_rtol, n, monkeypatch):
    redone = []

    def host_fallback(traced, offsets, aux, aux_offsets, box=None):
        cells = sppp_cells(traced, offsets, aux, aux_offsets, box)
        redone.append(int((~cells.bounded).sum()))
        return cells

    monkeypatch.setattr(device_cells, "sppp_cells", host_fallback)
    batch, box = sppp_batch(n, 1500, seed=n, eps=0.003)
    device, host = both(runtime, batch.traced, batch.offsets, batch.aux, batch.aux_offsets, box)
    assert_same_cells(device, host, area_rtol)
    assert (~host.bounded).sum() - sum(redone) > 100


# 6. Degenerate pixels give the host path's results
def degenerate_pixels():
    rng = np.random.default_rng(3)
    line = np.column_stack([np.linspace(-0.4, 0.4, 5), np.full(5, 0.1)])
    spread = rng.random((6, 2)) - 0.5
    strip = np.array([[-0.6, -0.6], [0.6, -0.6], [0.6, 0.6], [-0.6, 0.6]])
    pixels = [
        (np.zeros((0, 2)), strip),  # N = 0 with aux nuclei
        (np.zeros((0, 2)), np.zeros((0, 2))),  # N = 0, nothing at all
        (spread[:1], np.zeros((0, 2))),  # N = 1 alone: unbounded
        (spread[:1], strip),  # N = 1 in a frame: bounded
        (spread[:2], np.zeros((0, 2))),  # N = 2
        (line, np.zeros((0, 2))),  # collinear
        (line, np.column_stack([[-0.55, 0.55], [0.1, 0.1]])),  # collinear with aux on the line
        (np.concatenate([spread, spread[:2]]), strip),  # duplicated W nuclei
        (np.concatenate([spread[:3], strip[:1]]), strip),  # a W nucleus on an aux nucleus
        (np.repeat(spread[:1], 3, axis=0), np.zeros((0, 2))),  # one point three times
    ]
    traced = np.concatenate([t for t, _ in pixels])
    aux = np.concatenate([a for _, a in pixels])
    return (
        traced,
        offsets_of([len(t) for t, _ in pixels]),
        aux,
        offsets_of([len(a) for _, a in pixels]),
    )


def test_degenerate_pixels_match_host(runtime, area_rtol):
    traced, offsets, aux, aux_offsets = degenerate_pixels()
    device, host = both(runtime, traced, offsets, aux, aux_offsets, 0.55)
    assert_same_cells(device, host, area_rtol)
    assert host.bounded.any() and not host.bounded.all()


# 7. From the sampler's device buffers, without a host copy of the positions
def test_device_sample_sets_match_host(runtime, area_rtol):
    config = make_sampler("sppp", 64)
    sets = generate_sample_sets(runtime, config, 11, np.arange(700, dtype=np.uint32))
    box = float(np.float32(0.5 + config.eps))
    device = device_sppp_cells(runtime, sets, box)
    host_sets = sets.to_host(runtime.queue)
    host = sppp_cells(
        host_sets.traced.astype(np.float64),
        host_sets.offsets,
        host_sets.aux.astype(np.float64),
        host_sets.aux_offsets,
        box,
    )
    assert_same_cells(device, host, area_rtol)


# 7a. Only the grid cells that can hold traced nuclei get a work-item (traced_span): every
# traced sample of device sample sets falls in the span by the kernel's own float32 index, and
# the span leaves the strip's outer cells out (else this checks nothing)
@pytest.mark.parametrize("n", [64, 256, 1024])
def test_traced_span_holds_every_traced_sample(runtime, n):
    config = make_sampler("sppp", n)
    sets = generate_sample_sets(runtime, config, 5, np.arange(400, dtype=np.uint32))
    layout = device_cells._sample_set_layout(sets)
    first, count = device_cells.traced_span(layout)
    side, half = layout.grid_side, np.float32(layout.half_extent)
    inv_cell = np.float32(side) / (np.float32(2.0) * half)
    traced = sets.to_host(runtime.queue).traced.astype(np.float32)
    index = np.clip(np.floor((traced + half) * inv_cell).astype(np.int64), 0, side - 1)
    assert index.min() >= first and index.max() < first + count
    assert count < side


# 7a'. Traced nuclei anywhere in the grid, its border cells too (a span of the whole grid):
# their cells are all computed, as Qhull's
def test_traced_nuclei_in_border_grid_cells_match_qhull(runtime, area_rtol):
    rng = np.random.default_rng(23)
    traced = rng.uniform(-3.0, 3.0, (3000, 2))
    traced = traced[np.abs(traced).max(axis=1) > 2.6]  # a frame: the grid's outer cells
    aux = rng.uniform(-3.2, 3.2, (40, 2))
    offsets, aux_offsets = offsets_of([len(traced)]), offsets_of([len(aux)])
    device, host = both(runtime, traced, offsets, aux, aux_offsets, 3.0)
    assert_same_cells(device, host, area_rtol)
    assert host.bounded.mean() > 0.9


# 7b. A pixel's cells do not depend on the launch it is part of (tiling invariance)
def test_cells_bit_identical_across_launches(runtime):
    config = make_sampler("sppp", 64)
    every = np.arange(300, dtype=np.uint32)
    whole_sets = generate_sample_sets(runtime, config, 4, every)
    whole = device_sppp_cells(runtime, whole_sets, 0.6)
    part = device_sppp_cells(runtime, generate_sample_sets(runtime, config, 4, every[100:140]), 0.6)
    first, last = whole_sets.traced_offsets[100], whole_sets.traced_offsets[140]
    assert last - first == len(part.areas)
    np.testing.assert_array_equal(part.areas, whole.areas[first:last])
    np.testing.assert_array_equal(part.inside_box, whole.inside_box[first:last])


# 8. Cells the kernel cannot finish (vertex overflow) are recomputed on the host, exactly
def test_overflow_falls_back_to_host(runtime, area_rtol, monkeypatch):
    monkeypatch.setattr(device_cells, "MAX_VERTICES", 5)
    batch, box = sppp_batch(64, 60, seed=5)
    device, host = both(runtime, batch.traced, batch.offsets, batch.aux, batch.aux_offsets, box)
    assert device.stats.recomputed_pixels > 30
    assert_same_cells(device, host, area_rtol)


# 9. The estimators give the same estimates from device cells as from Qhull's
def test_estimates_from_device_cells_match(runtime, single_precision, monkeypatch):
    batch, _ = sppp_batch(64, 500, seed=9)
    traced, aux = rounded(batch.traced), rounded(batch.aux)
    values = np.column_stack(
        [
            np.abs(traced[:, 0] * traced[:, 1]) ** 0.5,
            (traced[:, 0] > 0.1).astype(float),
            np.ones(len(traced)),
        ]
    )
    samples = SampleSets(traced, batch.offsets, 64.0, aux, batch.aux_offsets, batch.eps)
    names = ["vor", "vor_sn", "fvor"]
    host = estimate_all(names, samples, values)
    monkeypatch.setattr(pixel_estimators, "sppp_cells", sppp_cells_backend(runtime))
    device = estimate_all(names, samples, values)
    rtol, atol = (SINGLE_SUMS_RTOL, 1e-6) if single_precision else (1e-9, 1e-12)
    for name in names:
        np.testing.assert_array_equal(device[name].needs_redraw, host[name].needs_redraw)
        np.testing.assert_allclose(
            device[name].estimates, host[name].estimates, rtol=rtol, atol=atol, equal_nan=True
        )


def test_bad_arguments_are_rejected(runtime):
    with pytest.raises(ParameterError, match="precision"):
        device_sppp_cells_from_arrays(
            runtime, np.zeros((1, 2)), [0, 1], np.zeros((0, 2)), [0, 0], precision="quad"
        )
    with pytest.raises(ParameterError, match="offsets"):
        device_sppp_cells_from_arrays(runtime, np.zeros((2, 2)), [0, 1], np.zeros((0, 2)), [0, 0])
    with pytest.raises(ParameterError, match="finite"):
        device_sppp_cells_from_arrays(
            runtime, np.full((1, 2), np.nan), [0, 1], np.zeros((0, 2)), [0, 0]
        )


# 11. Per-pixel sums on the device (device_sppp_sums) equal the host's sums of the same cells;
# non-finite radiance is counted and enters as 0; unbounded cells flag their pixel for redraw
# (precision "single" forced on every device: the sums of a device without cl_khr_fp64)
@pytest.mark.parametrize("eps, precision", [(None, "auto"), (0.08, "auto"), (None, "single")])
def test_device_sums_match_host_sums(runtime, eps, precision):
    config = make_sampler("sppp", 64, eps=eps)
    sets = generate_sample_sets(runtime, config, 9, np.arange(500, dtype=np.uint32))
    host = sets.to_host(runtime.queue)
    box = 0.5 + config.eps
    rng = np.random.default_rng(4)
    radiance = rng.uniform(0, 2, (sets.traced_total, 3)).astype(np.float32)
    poisoned = rng.choice(sets.traced_total, 40, replace=False)
    radiance[poisoned[:20], 0] = np.nan
    radiance[poisoned[20:], 2] = np.inf
    device = device_cells.device_sppp_sums(runtime, sets, runtime.upload(radiance), box, precision)

    cells = device_sppp_cells(runtime, sets, box, precision)
    bad = ~np.isfinite(radiance).all(axis=1)
    clean = np.where(bad[:, None], 0.0, radiance.astype(np.float64))  # as the render does
    samples = SampleSets(host.traced, host.offsets, 64.0, host.aux, host.aux_offsets, config.eps)
    expected = cell_sums(samples, clean, cells, kept=True)
    # Pixels with an undecided cell (none at the paper's eps, 24 at eps = 0.08: bounded
    # cells beyond the start box) are left to the host
    decided = ~device.fallback
    assert decided.sum() >= 450
    redraw = np.bincount(samples.pixel_index, ~cells.bounded, 500) > 0
    np.testing.assert_array_equal(device.redraw[decided], redraw[decided])
    assert (redraw.sum() > 50) == (eps is not None)
    np.testing.assert_array_equal(device.counts, samples.counts)
    np.testing.assert_array_equal(device.nonfinite, np.bincount(samples.pixel_index, bad, 500))
    ok = decided & ~redraw
    single = device_cells.resolve_precision(runtime, precision) == "single"
    # float64 sums of float64 areas, or float32 sums of float32 areas (in sample order both)
    rtol, atol = (SINGLE_SUMS_RTOL, 1e-6) if single else (1e-12, 1e-15)
    for name in ("area", "weighted", "kept_area", "kept_weighted"):
        np.testing.assert_allclose(
            getattr(device.sums, name)[ok],
            getattr(expected, name)[ok],
            rtol=rtol,
            atol=atol,
            err_msg=name,
        )

    # The plain sums (mc, mc_n, the variance layer) against the host's, in float64
    def per_pixel(x):
        return np.stack([np.bincount(samples.pixel_index, x[:, c], 500) for c in range(3)], 1)

    prtol = SINGLE_SUMS_RTOL if single else 1e-12
    np.testing.assert_allclose(device.sums.value, per_pixel(clean), rtol=prtol)
    np.testing.assert_allclose(device.sums.square, per_pixel(clean**2), rtol=prtol)


# 12. The plain sums alone (device_plain_sums: mc, mc_n and the variance layer without cells)
# are each pixel's sum f and sum f^2 in sample order, non-finite samples counted and taken as
# 0, and bit-identical to the plain sums the Voronoi sums kernel forms for the same samples
@pytest.mark.parametrize("sampler", ["sppp", "independent"])
def test_device_plain_sums_match_sequential_sums(runtime, single_precision, sampler):
    config = make_sampler(sampler, 48)
    sets = generate_sample_sets(runtime, config, 5, np.arange(300, dtype=np.uint32))
    host = sets.to_host(runtime.queue)
    rng = np.random.default_rng(8)
    radiance = rng.lognormal(0, 2, (sets.traced_total, 3)).astype(np.float32)
    poisoned = rng.choice(sets.traced_total, 30, replace=False)
    radiance[poisoned[:15], 1] = np.nan
    radiance[poisoned[15:], 0] = -np.inf
    device = device_cells.device_plain_sums(runtime, sets, runtime.upload(radiance))

    bad = ~np.isfinite(radiance).all(axis=1)
    clean = np.where(bad[:, None], 0.0, radiance.astype(np.float64))
    value, square = np.zeros((300, 3)), np.zeros((300, 3))
    for p in range(300):  # one pixel at a time, sample after sample, as the kernel
        for s in range(host.offsets[p], host.offsets[p + 1]):
            value[p] += clean[s]
            square[p] += clean[s] * clean[s]
    np.testing.assert_array_equal(device.counts, np.diff(host.offsets))
    np.testing.assert_array_equal(device.nonfinite, np.bincount(host.pixel_index, bad, 300))
    # float64 sums round like the host's; float32 ones (no fp64) within their stated bound
    rtol = SINGLE_SUMS_RTOL if single_precision else 1e-14
    np.testing.assert_allclose(device.sums.value, value, rtol=rtol, atol=0)
    np.testing.assert_allclose(device.sums.square, square, rtol=rtol, atol=0)
    assert not device.redraw.any() and not device.fallback.any()
    if sampler == "sppp":
        voronoi = device_cells.device_sppp_sums(
            runtime, sets, runtime.upload(radiance), 0.5 + config.eps
        )
        # Bit-identical on PoCL; Intel's CPU runtime rounds the pixels of a launch's last,
        # partial group of 8 work-items differently in either kernel (README: portability):
        # a few units in the last place there
        for name in ("value", "square"):
            np.testing.assert_allclose(
                getattr(device.sums, name), getattr(voronoi.sums, name), rtol=1e-15, atol=0
            )
        if "Portable Computing Language" in runtime.device.platform.name:
            np.testing.assert_array_equal(device.sums.value, voronoi.sums.value)
            np.testing.assert_array_equal(device.sums.square, voronoi.sums.square)


def test_device_sums_flag_undecided_cells_for_the_host(runtime, monkeypatch):
    monkeypatch.setattr(device_cells, "MAX_VERTICES", 5)
    config = make_sampler("sppp", 64)
    sets = generate_sample_sets(runtime, config, 2, np.arange(60, dtype=np.uint32))
    radiance = np.ones((sets.traced_total, 3), np.float32)
    device = device_cells.device_sppp_sums(
        runtime, sets, runtime.upload(radiance), 0.5 + config.eps
    )
    assert device.fallback.sum() > 30


# 11. VoronoiPolygon_Area (kernels/voronoi_polygon.h) against the cell's exact area: its fast
# path (every corner in one branch-free loop) and, when two consecutive edges lie on parallel
# bisectors (the same neighbour twice: the clipping may leave such a pair), its fallback that
# skips their corner, which lies on a straight side
POLYGON_AREA_KERNEL = """
#include "voronoi_polygon.h"
__kernel void polygon_area(int count, float2 nucleus, __global const float2 *edges,
                           __global area_real *area, __global int *inside)
{
    VoronoiPolygon poly;
    for (int k = 0; k < count; ++k) {
        poly.ex[k] = edges[k].x;
        poly.ey[k] = edges[k].y;
    }
    poly.count = count;
    bool in_box;
    area[0] = VoronoiPolygon_Area(&poly, nucleus, 0.5f, &in_box);
    inside[0] = in_box;
    area[1] = VoronoiPolygon_AreaSkipping(&poly, nucleus, 0.5f, &in_box);
    inside[1] = in_box;
}
"""


def bisector_polygon_area(nucleus: np.ndarray, neighbours: np.ndarray) -> float:
    """Shoelace area of the polygon whose consecutive edges lie on the bisectors of the nucleus
    and each neighbour (counter-clockwise), corners solved in float64."""
    corners = []
    for a, b in zip(np.roll(neighbours, 1, axis=0), neighbours, strict=True):
        normals = np.array([a - nucleus, b - nucleus])
        levels = 0.5 * (normals * (np.array([a, b]) + nucleus)).sum(axis=1)
        corners.append(np.linalg.solve(normals, levels))
    x, y = np.array(corners).T
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


@pytest.mark.parametrize("precision", ["single", "auto", "double"])
def test_polygon_area_skips_corners_of_parallel_edges(runtime, precision):
    import pyopencl as cl

    from clrender.runtime import build_options

    if precision == "double" and not has_fp64(runtime.device):
        pytest.skip("no cl_khr_fp64 on this device")
    defines = device_cells.kernel_defines(runtime, precision)
    program = cl.Program(runtime.context, POLYGON_AREA_KERNEL).build(
        options=build_options(tuple(sorted(defines.items())))
    )
    polygon_area = cl.Kernel(program, "polygon_area")
    single = device_cells.resolve_precision(runtime, precision) == "single"
    real = np.float32 if single else np.float64
    nucleus = np.array([0.1, 0.2], np.float32)
    angles = np.radians([5.0, 70.0, 130.0, 185.0, 250.0, 310.0])
    distances = np.array([0.11, 0.09, 0.12, 0.1, 0.13, 0.08])
    neighbours = (nucleus + distances[:, None] * np.c_[np.cos(angles), np.sin(angles)]).astype(
        np.float32
    )
    expected = bisector_polygon_area(nucleus.astype(np.float64), neighbours.astype(np.float64))
    for edges in (neighbours, np.insert(neighbours, 3, neighbours[2], axis=0)):
        area = np.zeros(2, real)
        inside = np.zeros(2, np.int32)
        polygon_area(
            runtime.queue,
            (1,),
            (1,),
            np.int32(len(edges)),
            cl.cltypes.make_float2(*nucleus),
            runtime.upload(np.ascontiguousarray(edges)),
            area_buf := runtime.allocate(area.nbytes),
            inside_buf := runtime.allocate(inside.nbytes),
        )
        cl.enqueue_copy(runtime.queue, area, area_buf)
        cl.enqueue_copy(runtime.queue, inside, inside_buf)
        np.testing.assert_allclose(area, expected, rtol=SINGLE_RTOL if single else AREA_RTOL)
        # The same corners on both paths, summed in another order (pairwise over 8 lanes)
        np.testing.assert_allclose(area[0], area[1], rtol=1e-6 if single else 1e-14)
        assert inside.tolist() == [1, 1]


def run_polygon_area(runtime, precision, nucleus, edges):
    """(VoronoiPolygon_Area, its inside flag) of one polygon on the device."""
    import pyopencl as cl

    from clrender.runtime import build_options

    defines = device_cells.kernel_defines(runtime, precision)
    program = cl.Program(runtime.context, POLYGON_AREA_KERNEL).build(
        options=build_options(tuple(sorted(defines.items())))
    )
    single = device_cells.resolve_precision(runtime, precision) == "single"
    area = np.zeros(2, np.float32 if single else np.float64)
    inside = np.zeros(2, np.int32)
    area_buf, inside_buf = runtime.allocate(area.nbytes), runtime.allocate(inside.nbytes)
    cl.Kernel(program, "polygon_area")(
        runtime.queue,
        (1,),
        (1,),
        np.int32(len(edges)),
        cl.cltypes.make_float2(*nucleus),
        runtime.upload(np.ascontiguousarray(edges, np.float32)),
        area_buf,
        inside_buf,
    )
    cl.enqueue_copy(runtime.queue, area, area_buf)
    cl.enqueue_copy(runtime.queue, inside, inside_buf)
    return float(area[0]), bool(inside[0])


# 11b. Polygons of 3 to 12 edges (8 lanes hold up to 8 corners; more take the loop): areas
# equal the exact ones, inside flags the corners' (some polygons cross the box x = 1/2)
@pytest.mark.parametrize("precision", ["single", "auto", "double"])
@pytest.mark.parametrize("k", [3, 4, 5, 7, 8, 9, 12])
def test_polygon_area_of_k_edges(runtime, precision, k):
    if precision == "double" and not has_fp64(runtime.device):
        pytest.skip("no cl_khr_fp64 on this device")
    single = device_cells.resolve_precision(runtime, precision) == "single"
    rng = np.random.default_rng(k)
    for nucleus_x in (0.1, 0.49):
        nucleus = np.array([nucleus_x, 0.2], np.float32)
        angles = np.linspace(0, 2 * np.pi, k, endpoint=False) + rng.uniform(0, 0.5, k)
        distances = rng.uniform(0.08, 0.13, k)
        neighbours = nucleus + distances[:, None] * np.c_[np.cos(angles), np.sin(angles)]
        neighbours = neighbours.astype(np.float32)
        nucleus64, edges64 = nucleus.astype(np.float64), neighbours.astype(np.float64)
        expected = bisector_polygon_area(nucleus64, edges64)
        corners = [
            np.linalg.solve(
                np.array([a - nucleus64, b - nucleus64]),
                0.5
                * np.array([(a - nucleus64) @ (a + nucleus64), (b - nucleus64) @ (b + nucleus64)]),
            )
            for a, b in zip(np.roll(edges64, 1, axis=0), edges64, strict=True)
        ]
        area, inside = run_polygon_area(runtime, precision, nucleus, neighbours)
        np.testing.assert_allclose(area, expected, rtol=SINGLE_RTOL if single else AREA_RTOL)
        assert inside == bool(np.all(np.abs(corners) <= 0.5))
        assert inside == (nucleus_x < 0.3)


# 15. Coincident nuclei share their cell equally, as on the host: every nucleus of a batch
# twice, through the walk (the default block) and through the clipping search (a block of 8
# nuclei, too small for any walk)
@pytest.mark.parametrize("block", [None, 8])
def test_duplicated_nuclei_share_their_cells_as_on_the_host(runtime, area_rtol, block, monkeypatch):
    if block is not None:
        defines = device_cells._defines
        monkeypatch.setattr(
            device_cells,
            "_defines",
            lambda precision: {**defines(precision), "VORONOI_BLOCK_CAPACITY": block},
        )
    batch = draw_sppp(np.random.default_rng(3), 64, 200)

    def twice(points):
        return np.repeat(np.asarray(points, np.float32).astype(np.float64).reshape(-1, 2), 2, 0)

    traced, aux = twice(batch.traced), twice(batch.aux)
    offsets, aux_offsets = 2 * batch.offsets, 2 * batch.aux_offsets
    box = float(np.float32(0.5 + batch.eps))
    host = sppp_cells(traced, offsets, aux, aux_offsets, box)
    device = device_sppp_cells_from_arrays(runtime, traced, offsets, aux, aux_offsets, box)
    assert (device.stats.walked_cells > 0) == (block is None)
    np.testing.assert_array_equal(device.bounded, host.bounded)
    bounded = host.bounded
    np.testing.assert_allclose(device.areas[bounded], host.areas[bounded], rtol=area_rtol)
    # the two copies of a nucleus got the same half of its cell
    np.testing.assert_array_equal(device.areas[0::2], device.areas[1::2])


def small_block_kernels(tmp_path_factory) -> Path:
    """A copy of the kernels folder whose block holds 8 nuclei, at a path named after the
    folder's contents beside pytest's numbered temporary folders: the same path in every
    session, so the device's compiler cache (keyed by paths and sources) builds it once, not
    in every session. Made in a session's folder and renamed into place (atomic: sessions at
    once each get a whole copy)."""
    digest = hashlib.sha256()
    for path in sorted(kernels_dir().iterdir()):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    folder = (
        tmp_path_factory.getbasetemp().parent / f"clrender-kernels-block8-{digest.hexdigest()[:16]}"
    )
    if folder.is_dir():
        assert "#define VORONOI_BLOCK_CAPACITY 8\n" in (folder / "voronoi_cells.cl").read_text()
        return folder
    draft = tmp_path_factory.mktemp("kernels")
    shutil.copytree(kernels_dir(), draft, dirs_exist_ok=True)
    source = draft / "voronoi_cells.cl"
    text = source.read_text()
    assert "#define VORONOI_BLOCK_CAPACITY 64\n" in text
    source.write_text(
        text.replace("#define VORONOI_BLOCK_CAPACITY 64\n", "#define VORONOI_BLOCK_CAPACITY 8\n")
    )
    with contextlib.suppress(OSError):  # another session renamed its copy there first
        draft.rename(folder)
    return folder


# 16. bench/device_voronoi_speed.py --variants times build options of the cell kernel against
# each other in one process and tells which give the first variant's cells bit for bit: the
# default spelled out does; a block too small for any walk (the clipping search, the same cells
# within rounding) does not, nor a 1 x 1 grid (GRID_SIDE: the whole set one block, over the
# block's capacity), nor a copy of the kernels folder whose block is that small (KERNELS),
# whose kernels are also the ones timed (the timing rounds once launched the default folder's)
def test_variant_timing_tells_identical_kernels_apart(runtime, tmp_path_factory, monkeypatch):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    import device_voronoi_speed

    assert device_voronoi_speed.parse_defines("-") == {}
    assert device_voronoi_speed.parse_defines("A,B=2") == {"A": True, "B": "2"}
    small_block = small_block_kernels(tmp_path_factory)
    variants = [
        "-",
        "VORONOI_BLOCK_CAPACITY=64",
        "VORONOI_BLOCK_CAPACITY=8",
        "GRID_SIDE=1",
        f"KERNELS={small_block}",
    ]
    folders = []  # (a KERNELS variant's call?, the kernels folder it looked its kernels up in)
    enqueue = device_cells._enqueue_cells

    def recording(runtime, layout, box, defines, area_bytes):
        folders.append(("CLRENDER_BENCH_KERNELS" in defines, kernels_dir()))
        return enqueue(runtime, layout, box, defines, area_bytes)

    monkeypatch.setattr(device_cells, "_enqueue_cells", recording)
    report = device_voronoi_speed.compare_variants(runtime, 16, variants, 2)
    default = kernels_dir()
    assert len(folders) == 3 * len(variants)  # the results' run, then 2 rounds
    assert [folder for bench, folder in folders if bench] == [small_block] * 3
    assert {folder for bench, folder in folders if not bench} == {default} != {small_block}
    rows = report["variants"]
    assert [row["identical_to_first"] for row in rows] == [True, True, False, False, False]
    assert rows[0]["ratio_to_first"] == [1.0, 1.0, 1.0]
    assert all(row["least_cpu_s_per_tile"] > 0 for row in rows)
    for row in rows:
        # The same cells: areas within rounding (single precision's at most)
        assert (row["areas_differing"] > 0) == (not row["identical_to_first"])
        assert row["largest_relative_area_difference"] < 1e-4


# 16b. --variants --processes pools the rounds of several processes and keeps each process's
# medians, so that one process that ran a variant slower throughout stands out
def test_variant_runs_of_several_processes_pool_their_rounds():
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    import device_voronoi_speed

    def report(first, second, identical=True):
        return {
            "variants": [
                {"variant": "-", "cpu_s_per_round": first, "identical_to_first": True},
                {"variant": "X", "cpu_s_per_round": second, "identical_to_first": identical},
            ]
        }

    fast = report([0.2, 0.4, 0.2], [0.2, 0.4, 0.2])
    slow = report([0.2, 0.2, 0.2], [0.24, 0.24, 0.24], identical=False)
    pooled = device_voronoi_speed.pool_variant_runs([fast, fast, slow])
    base, other = pooled["variants"]
    assert pooled["processes"] == 3
    assert base["ratio_to_first"] == [1.0, 1.0, 1.0] and base["identical_to_first"]
    np.testing.assert_allclose(other["process_median_ratio_to_first"], [1.0, 1.0, 1.2])
    np.testing.assert_allclose(other["process_median_cpu_s_per_tile"], [0.2, 0.2, 0.24])
    assert other["median_cpu_s_per_tile"] == 0.2  # the median process, not the slow one
    np.testing.assert_allclose(other["ratio_to_first"], [1.0, 1.0, 1.2])  # 9 rounds: 3 at 1.2
    assert not other["identical_to_first"]
    with pytest.raises(ValueError, match="reports of different variants"):
        device_voronoi_speed.pool_variant_runs([fast, {"variants": fast["variants"][:1]}])


# 17. On a CPU, kernels of one work-item per pixel spread their pixels evenly over the whole
# padded launch (kernels/voronoi_common.h Voronoi_SpreadPixel): PoCL deals work-groups to its
# threads in chunks from the front, so pixels packed at the front (a tile's 4096 in a launch of
# 65 536) all ran on one thread; and every pixel is still summed once
@pytest.mark.parametrize("pixels", [1, 500, 4096, 5000, 40_000, 70_000])
def test_per_pixel_launches_spread_their_pixels(runtime, pixels):
    kernel = runtime.kernel(device_cells.SUMS_KERNEL_FILE, "pixel_moments", {})
    local = runtime.kernel_local_size(kernel)
    stride = device_cells.pixel_stride(runtime, kernel, pixels)
    if not runtime.device.type & cl.device_type.CPU:  # a GPU keeps its pixels packed
        assert stride == 1
        return
    launch = launch_global_size(pixels * stride, local)
    last = (pixels - 1) * stride  # pixel p runs on work-item p * stride
    assert last < launch <= last + stride + local
    assert launch <= 2 * launch_global_size(pixels, local)


@pytest.mark.parametrize("pixels", [1, 4097, 70_000])
def test_spread_plain_sums_cover_every_pixel(runtime, pixels):
    config = make_sampler("independent", 2)
    sets = generate_sample_sets(runtime, config, 5, np.arange(pixels, dtype=np.uint32))
    radiance = np.arange(1, 3 * sets.traced_total + 1, dtype=np.float32).reshape(-1, 3)
    device = device_cells.device_plain_sums(runtime, sets, runtime.upload(radiance))
    expected = radiance.astype(np.float64).reshape(pixels, 2, 3).sum(axis=1)
    np.testing.assert_array_equal(device.sums.value, expected)


# 18. bench/device_voronoi_speed.py --stages: each stage's CPU per tile and its busiest thread's
# share of it (the stage's least wall time on an idle machine), never more than the whole; and
# the cell kernel's CPU per traced cell
def test_stage_accounting_reports_the_busiest_thread(runtime, monkeypatch):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    import device_voronoi_speed

    monkeypatch.setattr(device_voronoi_speed, "STAGE_PIXELS", 256)
    row = device_voronoi_speed.stage_accounting(runtime, 16, 1)
    for name, cpu in row["cpu_s_per_tile"].items():
        busiest = row["busiest_thread_s_per_tile"][name]
        assert 0 < busiest <= 1.01 * cpu + 1e-3, name
    # The cell kernel's CPU per traced cell, from its CPU per image
    tiles = device_voronoi_speed.IMAGE_PIXELS / device_voronoi_speed.STAGE_PIXELS
    cell_kernel = row["extra_cpu_s_per_image"]["cell kernel"] / tiles
    assert row["cell_kernel_cpu_ns_per_cell"] == pytest.approx(
        1e9 * cell_kernel / row["traced_nuclei"]
    )


def paired_and_single_cells(runtime, traced, offsets, aux, aux_offsets, box):
    """(areas, status) of the cell kernel as built (traced nuclei of a grid cell two at a time)
    and with VORONOI_NO_PAIRS (one at a time), on one float32 batch."""
    traced32, aux32 = rounded(traced).astype(np.float32), rounded(aux).astype(np.float32)
    flat = np.concatenate([traced32, aux32])
    layout = device_cells.CellLayout(
        runtime.upload(flat),
        np.asarray(offsets, np.int64),
        np.asarray(aux_offsets, np.int64),
        max(float(np.abs(flat).max()), 0.5),
        device_cells.grid_side(len(flat), len(offsets) - 1),
        float(np.abs(traced32).max()),
    )
    defines, real = device_cells.precision_setup(runtime, "auto")
    return [
        device_cells.launch_cell_kernels(runtime, layout, box, {**defines, **extra}, real)
        for extra in ({}, {"VORONOI_NO_PAIRS": True})
    ]


# 19. The kernel walks the traced nuclei of a grid cell two at a time, their steps interleaved
# (VoronoiCell_ComputePair): the areas and status bytes are bit for bit those of one nucleus at
# a time, whatever the two walks do: random pixels (odd and even counts per grid cell), a
# lattice (ties: one-way walks), every nucleus twice (coincident) and a pixel without
# auxiliary nuclei (walks that fail: the clipping search, unbounded cells)
def test_paired_walks_give_the_cells_of_single_walks(runtime):
    batch = draw_sppp(np.random.default_rng(11), 64, 40)
    k = 8
    centres = (np.arange(k) + 0.5) / k - 0.5
    lattice = np.array([(cx, cy) for cy in centres for cx in centres])
    ring = (np.arange(-1, k + 1) + 0.5) / k - 0.5
    lattice_aux = np.array([(x, y) for y in ring for x in ring if max(abs(x), abs(y)) > 0.5])
    doubled = np.repeat(rounded(batch.traced[: batch.offsets[1]]), 2, 0)
    doubled_aux = np.repeat(rounded(batch.aux[: batch.aux_offsets[1]]), 2, 0)
    bare = np.random.default_rng(12).uniform(-0.5, 0.5, (50, 2))
    traced = [rounded(batch.traced), lattice, doubled, bare]
    aux = [rounded(batch.aux), lattice_aux, doubled_aux, np.zeros((0, 2))]
    offsets = np.concatenate(
        [batch.offsets[:-1], batch.offsets[-1] + offsets_of([len(t) for t in traced[1:]])]
    )
    aux_offsets = np.concatenate(
        [batch.aux_offsets[:-1], batch.aux_offsets[-1] + offsets_of([len(a) for a in aux[1:]])]
    )
    box = float(np.float32(0.5 + batch.eps))
    (areas, status), (single_areas, single_status) = paired_and_single_cells(
        runtime, np.concatenate(traced), offsets, np.concatenate(aux), aux_offsets, box
    )
    np.testing.assert_array_equal(status, single_status)
    np.testing.assert_array_equal(areas.view(np.uint8), single_areas.view(np.uint8))
    # Every kind of walk met a partner: one-way walks, clipped cells, unbounded ones
    walked = (status & device_cells.STATUS_WALKED) != 0
    assert ((status & device_cells.STATUS_WALKED_ONE_WAY) != 0).any()
    assert (~walked & ((status & device_cells.STATUS_BOUNDED) != 0)).any()
    assert ((status & device_cells.STATUS_BOUNDED) == 0).any()
    assert walked.mean() > 0.9
