"""Device cells on the torus W (pvor; clrender.estimators.device_cells, kernel
voronoi_periodic_copies then the SPPP cell kernels) against two host references:

- the same point set: Qhull's cells (qhull_cells.sppp_cells) of the float32-rounded nuclei
  among their float32-rounded translates, which is what the device sees: to 1e-9 relative;
- the exact torus: qhull_cells.periodic_cells (float64 translates): to 1e-7 in area, the
  rounding of a translate to float32 (up to 6e-8) times a cell's perimeter.

Section 5 (undecided cells settled on the host, positions outside W refused) also covers cvor's
cells clipped to W, which share the torus cells' path (tests/test_device_clipped_cells.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from cell_sets import (
    EXACT_ATOL,
    assert_copy_cells,
    exact_atol,
    random_pixels,
    single,
)

from clrender.estimators import device_cells
from clrender.estimators.device_cells import (
    device_clipped_cells_from_arrays,
    device_clipped_sums,
    device_periodic_cells_from_arrays,
    device_periodic_sums,
)
from clrender.estimators.pixel import cell_sums
from clrender.estimators.qhull_cells import clipped_cells, periodic_cells, sppp_cells
from clrender.samples import SampleSets
from clrender.sampling import generate_sample_sets, make_sampler

# Single precision: within 1e-4 relative of the same set's cells (as tests/test_device_cells.py;
# a pixel's areas sum to 1 within 1.5e-6 relative at worst); the other tolerances are
# tests/cell_sets.py's
SINGLE_RTOL = 1e-4
SHIFTS = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dx, dy) != (0, 0)])


def float32_torus_copies(traced: np.ndarray, offsets: np.ndarray):
    """(wrapped nuclei, translates, translate offsets), rounded to float32 as the kernel does."""
    nuclei = np.asarray(traced, np.float32)
    nuclei = np.where(nuclei >= 0.5, nuclei - np.float32(1), nuclei)
    translates = (nuclei[:, None, :] + SHIFTS.astype(np.float32)).reshape(-1, 2)
    return nuclei.astype(np.float64), translates.astype(np.float64), 8 * np.asarray(offsets)


def assert_torus_cells(runtime, traced, offsets):
    return assert_copy_cells(
        runtime,
        traced,
        offsets,
        device_periodic_cells_from_arrays,
        float32_torus_copies,
        periodic_cells,
        SINGLE_RTOL,
    )


# 1. Random pixels of varying counts (empty ones among them) match both references
@pytest.mark.parametrize("mean, pixels", [(1, 40), (16, 300), (256, 40)])
def test_random_pixels_match_qhull(runtime, mean, pixels):
    counts = np.random.default_rng(mean).poisson(mean, pixels)
    traced, offsets = random_pixels(counts, seed=mean + 1)
    device = assert_torus_cells(runtime, traced, offsets)
    assert device.stats.recomputed_pixels == 0


# 2. Exact geometry: a lattice's cells are its squares; one nucleus owns the whole torus;
# coincident nuclei share a cell; collinear nuclei and nuclei on W's edges (x = 1/2 is the
# torus point x = -1/2) have their exact strip and square cells
@pytest.mark.parametrize(
    "nuclei, areas",
    [
        ([[0.1, -0.3]], [1.0]),
        ([[0.5, 0.5]], [1.0]),
        ([[-0.4, 0.0], [0.0, 0.0], [0.3, 0.0]], [0.35, 0.35, 0.3]),
        ([[0.1, 0.1], [0.1, 0.1], [0.1, -0.4]], [0.25, 0.25, 0.5]),
        ([[0.5, 0.0], [0.0, 0.0]], [0.5, 0.5]),
        ([[-0.5, 0.0], [0.5, 0.0], [0.0, 0.0]], [0.25, 0.25, 0.5]),
    ],
)
def test_exact_torus_cells(runtime, nuclei, areas):
    traced = np.array(nuclei, np.float64)
    device = assert_torus_cells(runtime, traced, np.array([0, len(traced)]))
    np.testing.assert_allclose(device.areas, areas, atol=exact_atol(runtime))


def test_lattice_cells_are_its_squares(runtime):
    side = (np.arange(8) + 0.5) / 8 - 0.5
    lattice = np.stack(np.meshgrid(side, side), -1).reshape(-1, 2)
    device = assert_torus_cells(runtime, lattice, np.array([0, 64]))
    np.testing.assert_allclose(device.areas, 1 / 64, rtol=1e-6)


# 3. Low-discrepancy pixel positions (pvor's use: stratified, sobol, zsobol with a toroidal
# shift) are decided on the device and match the references
@pytest.mark.parametrize("sampler", ["stratified", "sobol", "zsobol"])
def test_low_discrepancy_sets_match_qhull(runtime, sampler):
    config = make_sampler(sampler, 64, toroidal_shift=True)
    pixels = np.arange(400, dtype=np.uint32)
    sets = generate_sample_sets(runtime, config, 5, pixels, image_size=(32, 32))
    host = sets.to_host(runtime.queue)
    device = assert_torus_cells(runtime, host.traced.astype(np.float64), host.offsets)
    assert device.stats.recomputed_pixels == 0


# 4. Per-pixel sums from the sampler's device buffers equal the host's sums over the same
# cells; no pixel is redrawn; non-finite radiance is counted and enters as 0
# (precision "single" forced on every device: the sums of a device without cl_khr_fp64)
@pytest.mark.parametrize("precision", ["auto", "single"])
def test_device_sums_match_host_sums(runtime, precision):
    config = make_sampler("sobol", 64, toroidal_shift=True)
    pixels = np.arange(300, dtype=np.uint32)
    sets = generate_sample_sets(runtime, config, 8, pixels, image_size=(20, 15))
    host = sets.to_host(runtime.queue)
    rng = np.random.default_rng(3)
    radiance = rng.uniform(0, 2, (sets.traced_total, 3)).astype(np.float32)
    radiance[rng.choice(sets.traced_total, 10, replace=False), 1] = np.nan
    device = device_periodic_sums(runtime, sets, runtime.upload(radiance), precision)

    traced = host.traced.astype(np.float64)
    nuclei, translates, translate_offsets = float32_torus_copies(traced, host.offsets)
    cells = sppp_cells(nuclei, host.offsets, translates, translate_offsets)
    bad = ~np.isfinite(radiance).all(axis=1)
    clean = np.where(bad[:, None], 0.0, radiance.astype(np.float64))
    expected = cell_sums(SampleSets(traced, host.offsets, 64.0), clean, cells)
    assert not device.redraw.any() and not device.fallback.any()
    np.testing.assert_array_equal(device.nonfinite, np.bincount(host.pixel_index, bad, 300))
    # float64: the cells' areas to 1e-9 of the exact torus'; float32: to SINGLE_RTOL
    rtol = SINGLE_RTOL if single(runtime, precision) else 1e-9
    for name in ("area", "weighted"):
        np.testing.assert_allclose(
            getattr(device.sums, name), getattr(expected, name), rtol=rtol, err_msg=name
        )
    assert np.isnan(device.sums.kept_area).all()  # pvor has no W' filter (as on the host)


# 5. Cells the kernel cannot finish (vertex overflow) are recomputed on the host exactly; so
# are nuclei no work-item of the cell kernel reaches (its span made too narrow on purpose):
# never a stale area. Positions outside W are refused (the kernels' grid spans W's copies
# only). For the torus cells and the cells clipped to W (mirror images) alike.
COPY_KINDS = {
    "periodic": (device_periodic_cells_from_arrays, device_periodic_sums, periodic_cells),
    "clipped": (device_clipped_cells_from_arrays, device_clipped_sums, clipped_cells),
}


@pytest.mark.parametrize("kind", COPY_KINDS)
def test_overflow_falls_back_to_host(runtime, monkeypatch, kind):
    from_arrays, _, host_reference = COPY_KINDS[kind]
    monkeypatch.setattr(device_cells, "MAX_VERTICES", 5)
    traced, offsets = random_pixels(np.full(30, 16), seed=2)
    device = from_arrays(runtime, traced, offsets)
    assert device.stats.recomputed_pixels > 15
    np.testing.assert_allclose(
        device.areas, host_reference(traced, offsets).areas, rtol=0, atol=EXACT_ATOL
    )


@pytest.mark.parametrize("kind", COPY_KINDS)
def test_sums_flag_undecided_pixels_for_the_host(runtime, monkeypatch, kind):
    _, sums, _ = COPY_KINDS[kind]
    monkeypatch.setattr(device_cells, "MAX_VERTICES", 5)
    sets = generate_sample_sets(
        runtime, make_sampler("independent", 16), 2, np.arange(40, dtype=np.uint32)
    )
    radiance = np.ones((sets.traced_total, 3), np.float32)
    device = sums(runtime, sets, runtime.upload(radiance))
    assert device.fallback.sum() > 20 and not device.redraw.any()


@pytest.mark.parametrize("kind", COPY_KINDS)
def test_positions_outside_w_are_refused(runtime, kind):
    from_arrays, _, _ = COPY_KINDS[kind]
    traced, offsets = random_pixels(np.full(2, 16), seed=4)
    traced[5] = (-0.7, 0.1)
    with pytest.raises(device_cells.ParameterError, match=r"\(-0\.7.*at index 5"):
        from_arrays(runtime, traced, offsets)


@pytest.mark.parametrize("kind", COPY_KINDS)
def test_nuclei_outside_the_span_are_recomputed_on_the_host(runtime, monkeypatch, kind):
    from_arrays, _, host_reference = COPY_KINDS[kind]
    traced, offsets = random_pixels(np.full(30, 64), seed=5)
    # Fill the buffer pool with bounded-looking garbage first
    from_arrays(runtime, traced, offsets)
    full_span = device_cells.traced_span

    def narrow_span(layout):
        # Two grid cells off each side: where W's sides fall on grid lines (as on the 12 x 12
        # grid of n = 64 here), the span's outer cells are there for rounding only and hold
        # no traced nucleus
        first, count = full_span(layout)
        return first + 2, count - 4

    monkeypatch.setattr(device_cells, "traced_span", narrow_span)
    device = from_arrays(runtime, traced, offsets)
    assert device.stats.recomputed_pixels == 30
    np.testing.assert_allclose(
        device.areas, host_reference(traced, offsets).areas, rtol=0, atol=EXACT_ATOL
    )
