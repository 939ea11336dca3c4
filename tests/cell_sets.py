"""Shared by the tests of the device's torus and clipped cells: random pixels' nuclei, the
precision the device cell kernels run in, and the check of a pixel set's cells against both host
references (Qhull on the same float32 copies, and the exact cells)."""

import numpy as np

from clrender.estimators import device_cells
from clrender.estimators.qhull_cells import sppp_cells


def random_pixels(counts, seed) -> tuple[np.ndarray, np.ndarray]:
    """(positions, offsets): uniform nuclei in W, counts[p] for pixel p, float32-exact."""
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    traced = np.random.default_rng(seed).uniform(-0.5, 0.5, (offsets[-1], 2))
    return traced.astype(np.float32).astype(np.float64), offsets


def single(runtime, precision="auto") -> bool:
    """Whether the cell kernels compute in float32 alone for this precision on this device."""
    return device_cells.resolve_precision(runtime, precision) == "single"


# Against Qhull on the same float32 point set (what the device sees), and against the exact
# cells (float64 copies): the rounding of a copy to float32 (up to 6e-8) times a cell's perimeter
SAME_SET_RTOL = 1e-9
EXACT_ATOL = 1e-7
# Single precision (a device without cl_khr_fp64, or CLRENDER_NO_FP64): float32 areas within
# SINGLE_ATOL of the exact cells, a pixel's areas summing to 1 within it (the same-set relative
# tolerance is each kind's own)
SINGLE_ATOL = 1e-5


def exact_atol(runtime) -> float:
    return SINGLE_ATOL if single(runtime) else EXACT_ATOL


def assert_copy_cells(
    runtime, traced, offsets, device_cells_of, copies_of, exact_cells_of, single_rtol
):
    """The device's cells of each pixel's nuclei (device_cells_of: a *_cells_from_arrays) are
    bounded, equal Qhull's cells of the nuclei among their float32 copies (copies_of: the
    kernel's NumPy twin, (nuclei, copies, copy offsets)) and the exact cells (exact_cells_of),
    and tile W in each non-empty pixel. Returns the device's cells."""
    device = device_cells_of(runtime, traced, offsets)
    assert device.bounded.all() and device.inside_box is None
    nuclei, copies, copy_offsets = copies_of(traced, offsets)
    same_set = sppp_cells(nuclei, offsets, copies, copy_offsets)
    rtol = single_rtol if single(runtime) else SAME_SET_RTOL
    np.testing.assert_allclose(device.areas, same_set.areas, rtol=rtol, atol=0)
    exact = exact_cells_of(traced, offsets)
    np.testing.assert_allclose(device.areas, exact.areas, rtol=0, atol=exact_atol(runtime))
    counts = np.diff(offsets)
    # The cells of a non-empty pixel tile W: their areas sum to 1
    totals = np.add.reduceat(device.areas, offsets[:-1][counts > 0]) if counts.any() else []
    np.testing.assert_allclose(totals, 1.0, atol=SINGLE_ATOL if single(runtime) else 1e-6)
    return device
