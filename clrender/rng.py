"""NumPy reference of the device RNG (kernels/rng.h): Philox4x32-10 and its stream layout.

key = (seed, pixel), counter = (sample, dimension, redraw, 0). Vectorised over any number of
counters; used by the tests to check the kernels element by element.
"""

from __future__ import annotations

import numpy as np

PHILOX_M0 = np.uint64(0xD2511F53)
PHILOX_M1 = np.uint64(0xCD9E8D57)
PHILOX_W0 = np.uint32(0x9E3779B9)
PHILOX_W1 = np.uint32(0xBB67AE85)
AUX_BASE = 0x40000000
PIXEL_STREAM = 0xFFFFFFFF
MASK32 = np.uint64(0xFFFFFFFF)


def philox4x32_10(counters: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Philox4x32-10 of (M, 4) uint32 counters under (M, 2) uint32 keys -> (M, 4) uint32."""
    ctr = np.array(counters, dtype=np.uint32, copy=True).reshape(-1, 4)
    key = np.array(keys, dtype=np.uint32, copy=True).reshape(-1, 2)
    with np.errstate(over="ignore"):
        for round_index in range(10):
            if round_index > 0:
                key[:, 0] += PHILOX_W0
                key[:, 1] += PHILOX_W1
            prod0 = PHILOX_M0 * ctr[:, 0].astype(np.uint64)
            prod1 = PHILOX_M1 * ctr[:, 2].astype(np.uint64)
            hi0, lo0 = (
                (prod0 >> np.uint64(32)).astype(np.uint32),
                (prod0 & MASK32).astype(np.uint32),
            )
            hi1, lo1 = (
                (prod1 >> np.uint64(32)).astype(np.uint32),
                (prod1 & MASK32).astype(np.uint32),
            )
            ctr = np.column_stack(
                [hi1 ^ ctr[:, 1] ^ key[:, 0], lo1, hi0 ^ ctr[:, 3] ^ key[:, 1], lo0]
            )
    return ctr


def to_unit(bits: np.ndarray) -> np.ndarray:
    """32 random bits -> float32 strictly inside (0, 1), exactly as Rng_ToUnit."""
    return (
        ((bits >> np.uint32(9)).astype(np.float32) + np.float32(0.5)) * np.float32(2.0**-23)
    ).astype(np.float32)


def to_centered(bits: np.ndarray) -> np.ndarray:
    """32 random bits -> float32 strictly inside (-1/2, 1/2), exactly as Rng_ToCentered."""
    k = (bits >> np.uint32(8)).astype(np.int64) - 0x800000
    return ((k.astype(np.float32) + np.float32(0.5)) * np.float32(2.0**-24)).astype(np.float32)


def bits4(seed: int, pixel, sample, dim, redraw=0) -> np.ndarray:
    """Four 32-bit words per (pixel, sample, dim, redraw) slot, broadcast over arrays."""
    pixel, sample, dim, redraw = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.uint32) for a in (pixel, sample, dim, redraw))
    )
    counters = np.column_stack(
        [sample.ravel(), dim.ravel(), redraw.ravel(), np.zeros(sample.size, np.uint32)]
    )
    keys = np.column_stack([np.full(sample.size, seed, np.uint32), pixel.ravel()])
    return philox4x32_10(counters, keys).reshape(*sample.shape, 4)


def uniform4(seed: int, pixel, sample, dim, redraw=0) -> np.ndarray:
    """Four uniforms in (0, 1) per slot, as Rng_Uniform4."""
    return to_unit(bits4(seed, pixel, sample, dim, redraw))


def centered2(seed: int, pixel, sample, dim, redraw=0) -> np.ndarray:
    """Two coordinates in (-1/2, 1/2) per slot, as Rng_Centered2."""
    return to_centered(bits4(seed, pixel, sample, dim, redraw)[..., :2])
