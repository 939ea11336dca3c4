"""bench/oclgrind_check.py's work-arounds for two Oclgrind 26.03 faults, checked without Oclgrind:
its children turn host fills into writes of the same bytes (the uninitialised-value plugin keeps
a shadow as long as the last host store, so a fill left all but its last pattern "uninitialised"
for every later read), and render with overlap=False (a host store executed on a thread other
than the context's crashes that plugin)."""

import sys
from pathlib import Path

import numpy as np
import pyopencl as cl

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import oclgrind_check  # noqa: E402


def test_fills_become_writes_of_the_same_bytes(runtime, monkeypatch):
    fills = []

    def counted_fill(queue, mem, pattern, offset, size, wait_for=None):
        fills.append((offset, size))
        return original(queue, mem, pattern, offset, size, wait_for)

    original = cl.enqueue_fill_buffer
    monkeypatch.setattr(cl, "enqueue_fill_buffer", counted_fill)
    cases = [
        (np.uint8(4), 0, 13),  # device_cells' status bytes: a whole range from the start
        (np.uint32(0x01020304), 0, 16),
        (np.array([1.5, -2.0], np.float32), 0, 24),
        (np.uint8(7), 3, 5),  # not from the start: left to the real fill
    ]
    results = []
    for replaced in (False, True):
        if replaced:
            oclgrind_check.oclgrind_safe_fills()  # wraps counted_fill (restored after the test)
        for pattern, offset, size in cases:
            buf = cl.Buffer(runtime.context, cl.mem_flags.READ_WRITE, 32)
            cl.enqueue_copy(runtime.queue, buf, np.full(32, 0xAB, np.uint8))
            cl.enqueue_fill_buffer(runtime.queue, buf, pattern, offset, size)
            out = np.empty(32, np.uint8)
            cl.enqueue_copy(runtime.queue, out, buf)
            results.append(out)
    for before, after in zip(results[: len(cases)], results[len(cases) :], strict=True):
        np.testing.assert_array_equal(before, after)
    # every case filled once before the replacement, then only the offset one
    assert fills == [(0, 13), (0, 16), (0, 24), (3, 5), (3, 5)]


def test_children_render_on_one_thread(monkeypatch):
    import clrender.api
    import clrender.runtime

    calls = []
    monkeypatch.setattr(clrender.api, "render", lambda *args, **kwargs: calls.append(kwargs))
    monkeypatch.setattr(clrender.runtime, "MIN_LAUNCH_SIZE", clrender.runtime.MIN_LAUNCH_SIZE)
    monkeypatch.setenv("CLRENDER_NO_FP64", "0")  # the child sets it: restored after the test
    oclgrind_check.child_voronoi()
    assert len(calls) == 2
    assert all(kwargs.get("overlap") is False for kwargs in calls)
