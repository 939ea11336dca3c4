"""Does the host's way of waiting change how many threads run a kernel? Some CPU runtimes
(Intel's) run a kernel on their worker threads and on the host thread while it waits inside
the runtime; whether the host joins can depend on what it waits for.

    python bench/host_wait.py [--device SPEC] [--tiles 8] [--repeats 5] [--output DIR]

A spinning kernel (a few ms of arithmetic per work-item, 8 work-groups) is queued tile after
tile as clrender queues a tile's stages: a profiling marker, the kernel, a marker, a read of its
output into host memory, a marker (a render's tracing stage ends behind its counters' read);
the host waits for tile k once tile k + 1 is queued. Per way of waiting for tile k, medians
over repeats of wall and CPU seconds of the whole run (CPU / wall near the core count: every
core busy; near 1: one thread):

- read: the read alone (clrender's tiles before 2026-11-25);
- kernel: the kernel's own event, then the read;
- marker: the marker right behind the kernel, then the read;
- last-marker: the marker behind the read, then the read (a stage's end marker:
  QueuedTile.collect now);
- finish: the whole queue (which also waits for tile k + 1);
- sleep: poll the read's status with a 1 ms sleep (the host outside the runtime).

JSON goes to DIR/results.json (default bench/results/host_wait/).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import command_line, machine, write_json  # noqa: E402

from clrender.runtime import create_runtime  # noqa: E402

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "results" / "host_wait"
WAYS = ("read", "kernel", "marker", "last-marker", "finish", "sleep")
SPIN_SOURCE = """
__kernel void spin(__global float *out, const int steps)
{
    float x = (float)get_global_id(0) * 1e-6f;
    for (int k = 0; k < steps; k++)  /* dependent arithmetic: no vectorised shortcut */
        x = x * 0.9999f + 0.5f;
    out[get_global_id(0)] = x;
}
"""


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", help="as clrender's --device (default: PYOPENCL_CTX)")
    parser.add_argument("--tiles", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--steps", type=int, default=1_600_000, help="loop steps a work-item")
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT)
    return parser.parse_args(argv)


def wait_for_tile(way: str, queue: cl.CommandQueue, kernel, marker, read, last) -> None:
    if way in ("kernel", "marker", "last-marker"):
        {"kernel": kernel, "marker": marker, "last-marker": last}[way].wait()
    elif way == "finish":
        queue.finish()
    elif way == "sleep":
        while read.command_execution_status != cl.command_execution_status.COMPLETE:
            time.sleep(0.001)
    read.wait()


def timed_run(way: str, queue, spin, buffer, host, tiles: int, steps: int) -> tuple[float, float]:
    """Wall and CPU seconds of `tiles` tiles, each waited for once the next is queued."""
    wall, cpu = time.perf_counter(), time.process_time()
    waiting = None
    for index in range(tiles + 1):
        queued = None
        if index < tiles:
            cl.enqueue_marker(queue)
            kernel = spin(queue, (host.size,), (host.size // 8,), buffer, np.int32(steps))
            marker = cl.enqueue_marker(queue)
            read = cl.enqueue_copy(queue, host, buffer, is_blocking=False)
            last = cl.enqueue_marker(queue)
            queue.flush()
            queued = (kernel, marker, read, last)
        if waiting is not None:
            wait_for_tile(way, queue, *waiting)
        waiting = queued
    queue.finish()
    return time.perf_counter() - wall, time.process_time() - cpu


def main(argv=None) -> None:
    args = parse_args(argv)
    runtime = create_runtime(args.device)
    queue = runtime.queue
    spin = cl.Kernel(cl.Program(runtime.context, SPIN_SOURCE).build(), "spin")
    host = np.empty(512, np.float32)
    buffer = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, host.nbytes)
    timed_run("finish", queue, spin, buffer, host, 1, args.steps)  # built and warm
    runs: dict[str, list[tuple[float, float]]] = {way: [] for way in WAYS}
    for _ in range(args.repeats):
        for way in WAYS:  # alternating, so load changes fall on every way alike
            runs[way].append(timed_run(way, queue, spin, buffer, host, args.tiles, args.steps))
    results = {}
    print(f"{runtime.device.platform.name} / {runtime.device.name}")
    for way in WAYS:
        wall = statistics.median(w for w, _ in runs[way])
        cpu = statistics.median(c for _, c in runs[way])
        results[way] = {"wall_s": wall, "cpu_s": cpu, "cpu_per_wall": cpu / wall}
        print(f"  {way:12s} wall {wall:.3f} s, CPU {cpu:.3f} s, CPU/wall {cpu / wall:.2f}")
    write_json(
        args.output / "results.json",
        {
            "command": command_line("host_wait.py", argv),
            "machine": machine(),
            "platform": runtime.device.platform.name,
            "device": runtime.device.name,
            "tiles": args.tiles,
            "steps": args.steps,
            "repeats": args.repeats,
            "ways": results,
        },
    )


if __name__ == "__main__":
    main()
