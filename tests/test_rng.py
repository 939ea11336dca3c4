"""Philox4x32-10: Random123 known answers on the device and in NumPy, and element-by-element
agreement between the kernel and the NumPy reference."""

import numpy as np
import pyopencl as cl
import pytest

from clrender import rng
from clrender.runtime import padded_global_size
from clrender.selfcheck import PHILOX_KAT, device_philox, run_self_check


@pytest.mark.parametrize("counter, key, expected", PHILOX_KAT)
def test_numpy_philox_matches_random123(counter, key, expected):
    got = rng.philox4x32_10(np.array([counter]), np.array([key]))[0]
    assert tuple(int(v) for v in got) == expected


@pytest.mark.parametrize("counter, key, expected", PHILOX_KAT)
def test_device_philox_matches_random123(runtime, counter, key, expected):
    got = device_philox(runtime, np.array([counter]), np.array([key]))[0]
    assert tuple(int(v) for v in got) == expected


def test_self_check_passes(runtime):
    ok, message = run_self_check(runtime)
    assert ok, message


def test_device_philox_equals_numpy_on_random_inputs(runtime):
    gen = np.random.default_rng(1)
    counters = gen.integers(0, 2**32, size=(10_000, 4), dtype=np.uint32)
    keys = gen.integers(0, 2**32, size=(10_000, 2), dtype=np.uint32)
    np.testing.assert_array_equal(
        device_philox(runtime, counters, keys), rng.philox4x32_10(counters, keys)
    )


def _device_uniform_slots(runtime, seed, slots):
    slots = np.ascontiguousarray(slots, np.uint32)
    out = np.empty((len(slots), 4), np.float32)
    mf = cl.mem_flags
    slots_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=slots)
    out_buf = cl.Buffer(runtime.context, mf.WRITE_ONLY, size=out.nbytes)
    kernel = runtime.kernel("rng_test.cl", "uniform_slots")
    kernel(
        runtime.queue,
        (padded_global_size(len(slots)),),
        (runtime.local_size,),
        np.uint32(len(slots)),
        np.uint32(seed),
        slots_buf,
        out_buf,
    )
    cl.enqueue_copy(runtime.queue, out, out_buf)
    return out


def test_device_uniforms_equal_numpy_bit_for_bit(runtime):
    gen = np.random.default_rng(2)
    slots = gen.integers(0, 2**32, size=(5_000, 4), dtype=np.uint32)
    device = _device_uniform_slots(runtime, 1234, slots)
    reference = rng.uniform4(1234, slots[:, 0], slots[:, 1], slots[:, 2], slots[:, 3])
    np.testing.assert_array_equal(device, reference)


def test_unit_floats_are_strictly_inside_the_open_interval():
    extremes = np.array([0, 1, 2**32 - 1, 2**31, 2**31 - 1], np.uint32)
    unit = rng.to_unit(extremes)
    centered = rng.to_centered(extremes)
    assert np.all((unit > 0) & (unit < 1))
    assert np.all((centered > -0.5) & (centered < 0.5))


def test_streams_differ_in_every_coordinate():
    base = rng.bits4(7, 3, 5, 1, 0)
    for other in (
        rng.bits4(8, 3, 5, 1, 0),
        rng.bits4(7, 4, 5, 1, 0),
        rng.bits4(7, 3, 6, 1, 0),
        rng.bits4(7, 3, 5, 2, 0),
        rng.bits4(7, 3, 5, 1, 1),
    ):
        assert not np.array_equal(base, other)
