"""Device cells clipped to W (cvor; clrender.estimators.device_cells, kernel
voronoi_mirror_copies then the SPPP cell kernels) against two host references:

- the same point set: Qhull's cells (qhull_cells.sppp_cells) of the float32 nuclei among their
  float32-rounded mirror images in W's sides, which is what the device sees: to 1e-9 relative;
- the exact clipped cells: qhull_cells.clipped_cells (float64 mirrors): to 1e-7 in area, the
  rounding of a mirror to float32 (up to 6e-8, moving a side by half that) times a cell's
  perimeter (measured: 3.2e-8 at worst).
"""

from __future__ import annotations

import numpy as np
import pytest
from cell_sets import (
    assert_copy_cells,
    exact_atol,
    random_pixels,
    single,
)

from clrender.estimators.device_cells import device_clipped_cells_from_arrays, device_clipped_sums
from clrender.estimators.pixel import cell_sums
from clrender.estimators.qhull_cells import clipped_cells, sppp_cells
from clrender.samples import SampleSets
from clrender.sampling import generate_sample_sets, make_sampler

# Single precision: within 2e-4 relative of the same set's cells (measured: 1.13e-4 at worst over
# 10 142 random cells, a cell of area 0.01 off by 1.1e-6: the walk's float32 arithmetic on mirrors
# up to 1.5 in magnitude); the other tolerances are tests/cell_sets.py's
SINGLE_RTOL = 2e-4


def float32_mirrors(traced: np.ndarray, offsets: np.ndarray):
    """(nuclei, mirrors, mirror offsets), rounded to float32 as the kernel does (an independent
    NumPy twin of voronoi_mirror_copies)."""
    inside = np.float32(0.5) - np.float32(2**-25)  # the largest float below 1/2
    nuclei = np.clip(np.asarray(traced, np.float32), -inside, inside)
    one = np.float32(1)
    x, y = nuclei[:, 0], nuclei[:, 1]
    mirrors = np.stack(
        [
            np.stack([one - x, y], -1),
            np.stack([-one - x, y], -1),
            np.stack([x, one - y], -1),
            np.stack([x, -one - y], -1),
        ],
        1,
    ).reshape(-1, 2)
    return nuclei.astype(np.float64), mirrors.astype(np.float64), 4 * np.asarray(offsets)


def assert_clipped_cells(runtime, traced, offsets):
    return assert_copy_cells(
        runtime,
        traced,
        offsets,
        device_clipped_cells_from_arrays,
        float32_mirrors,
        clipped_cells,
        SINGLE_RTOL,
    )


# 1. Random pixels of varying counts (empty ones among them) match both references
@pytest.mark.parametrize("mean, pixels", [(1, 40), (16, 300), (256, 40)])
def test_random_pixels_match_qhull(runtime, mean, pixels):
    counts = np.random.default_rng(mean).poisson(mean, pixels)
    traced, offsets = random_pixels(counts, seed=mean + 7)
    device = assert_clipped_cells(runtime, traced, offsets)
    assert device.stats.recomputed_pixels == 0


# 2. Exact geometry: one nucleus owns W (also on a side or a corner, where it would share its
# cell with its own mirror if the kernel did not move it inside); two, three and coincident
# nuclei have their exact strips; a lattice's cells are its squares; a nucleus near a corner
@pytest.mark.parametrize(
    "nuclei, areas",
    [
        ([[0.1, -0.3]], [1.0]),
        ([[0.5, 0.0]], [1.0]),
        ([[-0.5, 0.5]], [1.0]),
        ([[-0.25, 0.2], [0.25, 0.2]], [0.5, 0.5]),
        ([[-0.4, 0.0], [0.0, 0.0], [0.3, 0.0]], [0.3, 0.35, 0.35]),
        ([[0.1, 0.1], [0.1, 0.1], [0.1, -0.4]], [0.325, 0.325, 0.35]),
        ([[0.45, 0.45], [0.0, 0.0]], [0.15125, 0.84875]),  # the corner beyond x + y = 0.45
    ],
)
def test_exact_clipped_cells(runtime, nuclei, areas):
    traced = np.array(nuclei, np.float64)
    device = assert_clipped_cells(runtime, traced, np.array([0, len(traced)]))
    np.testing.assert_allclose(device.areas, areas, atol=exact_atol(runtime))
    assert device.stats.recomputed_pixels == 0  # decided on the device, sides and corners too


def test_lattice_cells_are_its_squares(runtime):
    side = (np.arange(8) + 0.5) / 8 - 0.5
    lattice = np.stack(np.meshgrid(side, side), -1).reshape(-1, 2)
    device = assert_clipped_cells(runtime, lattice, np.array([0, 64]))
    np.testing.assert_allclose(device.areas, 1 / 64, rtol=1e-6)


# 3. Pixel positions of every kind of sampler are decided on the device and match
@pytest.mark.parametrize("sampler", ["independent", "stratified", "sobol", "zsobol", "sppp"])
def test_sampler_sets_match_qhull(runtime, sampler):
    config = make_sampler(sampler, 64)
    pixels = np.arange(400, dtype=np.uint32)
    sets = generate_sample_sets(runtime, config, 5, pixels, image_size=(32, 32))
    host = sets.to_host(runtime.queue)
    device = assert_clipped_cells(runtime, host.traced.astype(np.float64), host.offsets)
    assert device.stats.recomputed_pixels == 0


# 4. Per-pixel sums from the sampler's device buffers equal the host's sums over the same
# cells; no pixel is redrawn; non-finite radiance is counted and enters as 0
# (precision "single" forced on every device: the sums of a device without cl_khr_fp64)
@pytest.mark.parametrize("precision", ["auto", "single"])
def test_device_sums_match_host_sums(runtime, precision):
    config = make_sampler("stratified", 64)
    pixels = np.arange(300, dtype=np.uint32)
    sets = generate_sample_sets(runtime, config, 8, pixels, image_size=(20, 15))
    host = sets.to_host(runtime.queue)
    rng = np.random.default_rng(3)
    radiance = rng.uniform(0, 2, (sets.traced_total, 3)).astype(np.float32)
    radiance[rng.choice(sets.traced_total, 10, replace=False), 1] = np.nan
    device = device_clipped_sums(runtime, sets, runtime.upload(radiance), precision)

    traced = host.traced.astype(np.float64)
    nuclei, mirrors, mirror_offsets = float32_mirrors(traced, host.offsets)
    cells = sppp_cells(nuclei, host.offsets, mirrors, mirror_offsets)
    bad = ~np.isfinite(radiance).all(axis=1)
    clean = np.where(bad[:, None], 0.0, radiance.astype(np.float64))
    expected = cell_sums(SampleSets(traced, host.offsets, 64.0), clean, cells)
    assert not device.redraw.any() and not device.fallback.any()
    np.testing.assert_array_equal(device.nonfinite, np.bincount(host.pixel_index, bad, 300))
    rtol = SINGLE_RTOL if single(runtime, precision) else 1e-9
    for name in ("area", "weighted"):
        np.testing.assert_allclose(
            getattr(device.sums, name), getattr(expected, name), rtol=rtol, err_msg=name
        )
    assert np.isnan(device.sums.kept_area).all()  # cvor has no W' filter (as on the host)


# 5. Undecided cells and positions outside W: tests/test_device_periodic_cells.py, for both kinds
