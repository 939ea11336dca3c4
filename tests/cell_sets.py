"""Shared by the tests of the device's torus and clipped cells: random pixels' nuclei, and the
precision the device cell kernels run in."""

import numpy as np

from clrender.estimators import device_cells


def random_pixels(counts, seed) -> tuple[np.ndarray, np.ndarray]:
    """(positions, offsets): uniform nuclei in W, counts[p] for pixel p, float32-exact."""
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    traced = np.random.default_rng(seed).uniform(-0.5, 0.5, (offsets[-1], 2))
    return traced.astype(np.float32).astype(np.float64), offsets


def single(runtime, precision="auto") -> bool:
    """Whether the cell kernels compute in float32 alone for this precision on this device."""
    return device_cells.resolve_precision(runtime, precision) == "single"
