"""Device self-check: the Philox known-answer vectors computed by the selected device.

`python -m clrender` (and `python -m clrender devices`) builds kernels/selfcheck.cl, the
product's one self-check kernel: raw Philox4x32-10 blocks of kernels/rng.h, the generator every
sample position and path depends on, compared with Random123's known answers.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrender.runtime import Runtime

# Random123 tests/kat_vectors, philox4x32 10: counter, key, expected output.
PHILOX_KAT = (
    (
        (0x00000000, 0x00000000, 0x00000000, 0x00000000),
        (0x00000000, 0x00000000),
        (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8),
    ),
    (
        (0xFFFFFFFF, 0xFFFFFFFF, 0xFFFFFFFF, 0xFFFFFFFF),
        (0xFFFFFFFF, 0xFFFFFFFF),
        (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD),
    ),
    (
        (0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344),
        (0xA4093822, 0x299F31D0),
        (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1),
    ),
)


def device_philox(runtime: Runtime, counters: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Philox4x32-10 of (M, 4) counters under (M, 2) keys, computed on the device."""
    counters = np.ascontiguousarray(counters, np.uint32).reshape(-1, 4)
    keys = np.ascontiguousarray(keys, np.uint32).reshape(-1, 2)
    out = np.empty_like(counters)
    ctr_buf, key_buf = runtime.upload(counters), runtime.upload(keys)
    out_buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=out.nbytes)
    kernel = runtime.kernel("selfcheck.cl", "philox_blocks")
    runtime.launch_1d(
        kernel,
        len(out),
        np.uint32(len(out)),
        ctr_buf,
        key_buf,
        out_buf,
    )
    cl.enqueue_copy(runtime.queue, out, out_buf)
    return out


def run_self_check(runtime: Runtime) -> tuple[bool, str]:
    """Build the self-check kernel and compare its Philox blocks with the Random123 vectors."""
    counters = np.array([kat[0] for kat in PHILOX_KAT], np.uint32)
    keys = np.array([kat[1] for kat in PHILOX_KAT], np.uint32)
    expected = np.array([kat[2] for kat in PHILOX_KAT], np.uint32)
    got = device_philox(runtime, counters, keys)
    passed = int(np.all(got == expected, axis=1).sum())
    ok = passed == len(PHILOX_KAT)
    return ok, f"Philox4x32-10 known-answer vectors: {passed}/{len(PHILOX_KAT)} match"
