"""Speed of the Voronoi stage against Qhull's bare Delaunay triangulation.

    python bench/voronoi_speed.py [--quick] [--repeats K] [--no-device] [--out DIR]

The stage is estimate("vor", ...): input checks, every cell area (layout, Qhull calls, exactness
checks, recomputed pixels) and the per-pixel sums. It is compared with bare
scipy.spatial.Delaunay on the same points, with the same options (QHULL_OPTIONS):

- "same calls": exactly the point arrays the stage hands to Qhull (several pixels per call);
  this is the target ratio, stage / bare <= 1.3;
- "per pixel": one call per pixel's own point set (W + aux nuclei), for reference.

Times are CPU seconds of this process (time.process_time), so that other processes on a shared
machine count less; each configuration is warmed up once, then the stage and both bare loops
run in turn in alternating order (ABC, CBA, ...), K times (3K for the one-pixel row, whose
calls are short), and the medians of one run give the ratios; each row records its count
("repeats"). Rows: one 4096-sample pixel, n = 64 ... 4096 over ~0.2 M samples each, and a batch
of 4096 pixels at n = 256. One thread (Qhull is single-threaded).

Then the same one-pixel estimate with the cells from the OpenCL cell kernel
(clrender.estimators.device_cells, the render's default backend) on one core: child processes
pinned to one CPU core (sched_setaffinity) run it with POCL_MAX_PTHREAD_COUNT=1 (PoCL's CPU
device then has one worker thread), timing the whole call (float32 upload, grid and cell
kernels, read-back, host fallbacks, the estimate) in wall and CPU seconds; the figure is the
median over 5 processes of each one's median (of 3K calls); areas are checked against Qhull's.
Skipped with --no-device.

Writes DIR/results.json (default bench/results/voronoi_speed/): every row, the clock, and the
machine's load before and after ("machine_before", "machine_after"; the machine is shared).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from common import machine, positive_int, write_json  # noqa: E402
from scipy.spatial import Delaunay  # noqa: E402

from clrender.estimators import estimate  # noqa: E402
from clrender.estimators.delaunay import QHULL_OPTIONS  # noqa: E402
from clrender.estimators.qhull_cells import (  # noqa: E402
    POINTS_PER_QHULL_CALL,
    qhull_point_arrays,
)
from clrender.sppp import draw_sppp  # noqa: E402

TARGET_RATIO = 1.3
TARGET_ONE_PIXEL_MS = 2.0
ONE_PIXEL_REPEAT_FACTOR = 3  # the one-pixel rows (short calls) take this many times K repeats
DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "voronoi_speed"


def cpu_time(fn) -> float:
    start = time.process_time()
    fn()
    return time.process_time() - start


def interleaved_times(fns: dict, repeats: int) -> dict[str, list[float]]:
    """CPU times of each function over `repeats` turns, alternating the order."""
    names = list(fns)
    for name in names:  # warm-up: caches, allocator, lazy imports
        fns[name]()
    times = {name: [] for name in names}
    for turn in range(repeats):
        for name in names if turn % 2 == 0 else names[::-1]:
            times[name].append(cpu_time(fns[name]))
    return times


def measure(n: int, pixels: int, repeats: int, rng: np.random.Generator) -> dict:
    batch = draw_sppp(rng, n, pixels)
    values = np.abs(batch.traced[:, 0] * batch.traced[:, 1])
    arrays = qhull_point_arrays(batch.traced, batch.offsets, batch.aux, batch.aux_offsets)
    per_pixel = [
        np.concatenate(
            [
                batch.traced[batch.offsets[p] : batch.offsets[p + 1]],
                batch.aux[batch.aux_offsets[p] : batch.aux_offsets[p + 1]],
            ]
        )
        for p in range(pixels)
    ]

    def stage():
        result = estimate("vor", batch, values)
        stage.tessellation = result.stats.tessellation

    def bare_same_calls():
        for points in arrays:
            Delaunay(points, qhull_options=QHULL_OPTIONS)

    def bare_per_pixel():
        for points in per_pixel:
            Delaunay(points, qhull_options=QHULL_OPTIONS)

    times = interleaved_times(
        {"stage": stage, "bare_same_calls": bare_same_calls, "bare_per_pixel": bare_per_pixel},
        repeats,
    )
    t = {name: float(np.median(v)) for name, v in times.items()}
    samples_count = len(batch.traced)
    points = samples_count + len(batch.aux)
    return {
        "n": n,
        "pixels": pixels,
        "repeats": repeats,
        "samples": samples_count,
        "points": points,
        "qhull_calls": len(arrays),
        "recomputed_pixels": stage.tessellation.recomputed_pixels,
        "stage_ms_per_pixel": 1e3 * t["stage"] / pixels,
        "bare_same_calls_ms_per_pixel": 1e3 * t["bare_same_calls"] / pixels,
        "bare_per_pixel_ms_per_pixel": 1e3 * t["bare_per_pixel"] / pixels,
        "ratio_same_calls": t["stage"] / t["bare_same_calls"],
        "ratio_per_pixel": t["stage"] / t["bare_per_pixel"],
        "us_per_sample": 1e6 * t["stage"] / samples_count,
        "bare_us_per_point": 1e6 * t["bare_same_calls"] / points,
        "cpu_seconds": times,
    }


def device_one_pixel(repeats: int, seed: int) -> dict:
    """One 4096-sample pixel's vor estimate with device cells, timed in this process."""
    from clrender.estimators.device_cells import device_sppp_cells_from_arrays
    from clrender.estimators.qhull_cells import sppp_cells
    from clrender.runtime import create_runtime

    runtime = create_runtime(None)
    batch = draw_sppp(np.random.default_rng(seed), 4096, 1)
    values = np.abs(batch.traced[:, 0] * batch.traced[:, 1])

    def run():
        cells = device_sppp_cells_from_arrays(
            runtime, batch.traced, batch.offsets, batch.aux, batch.aux_offsets
        )
        return estimate("vor", batch, values, {"sppp": cells}), cells

    result, cells = run()  # warm-up: kernel build, first launch
    walls, cpus = [], []
    for _ in range(repeats):
        wall0, cpu0 = time.perf_counter(), time.process_time()
        run()
        walls.append(time.perf_counter() - wall0)
        cpus.append(time.process_time() - cpu0)
    rounded = [np.asarray(a, np.float32).astype(np.float64) for a in (batch.traced, batch.aux)]
    host = sppp_cells(rounded[0], batch.offsets, rounded[1], batch.aux_offsets)
    return {
        "samples": len(batch.traced),
        "points": len(batch.traced) + len(batch.aux),
        "device": runtime.describe(),
        "repeats": repeats,
        "wall_ms": 1e3 * float(np.median(walls)),
        "cpu_ms": 1e3 * float(np.median(cpus)),
        "walked_cells": cells.stats.walked_cells,
        "max_relative_area_difference": float(np.nanmax(np.abs(cells.areas / host.areas - 1.0))),
        "estimate": float(result.estimates[0]),
    }


def pin_to_one_core() -> None:
    """Confine this process (and the threads it starts later, PoCL's worker among them) to
    one CPU core, where the OS allows it (Linux)."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def device_one_pixel_on_one_core(repeats: int, processes: int = 5) -> dict | None:
    """device_one_pixel in child processes pinned to one core, whose PoCL device has one
    worker thread: the median over `processes` children of each child's median, with every
    child's figures."""
    env = dict(os.environ, POCL_MAX_PTHREAD_COUNT="1")
    children = []
    for _ in range(processes):
        child = subprocess.run(
            [sys.executable, __file__, "--device-one-pixel-child", "--repeats", str(repeats)],
            env=env,
            capture_output=True,
            text=True,
        )
        if child.returncode != 0:
            print(f"device one-pixel measurement failed:\n{child.stderr.strip()}")
            return None
        children.append(json.loads(child.stdout.strip().splitlines()[-1]))
    summary = dict(children[0])
    for key in ("wall_ms", "cpu_ms"):
        summary[key] = float(np.median([c[key] for c in children]))
        summary[f"{key}_per_process"] = [c[key] for c in children]
    summary["max_relative_area_difference"] = max(
        c["max_relative_area_difference"] for c in children
    )
    summary["processes"] = processes
    return summary


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: 4 pixels per n, a batch of 256 pixels at n = 64, K = 3",
    )
    parser.add_argument(
        "--repeats",
        type=positive_int,
        default=None,
        metavar="K",
        help="timed turns per row (default 7, --quick 3; the one-pixel rows take "
        f"{ONE_PIXEL_REPEAT_FACTOR}K)",
    )
    parser.add_argument(
        "--no-device", action="store_true", help="skip the one-pixel measurement with device cells"
    )
    parser.add_argument("--device-one-pixel-child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--out",
        type=Path,
        default=DEFAULT_OUT,
        metavar="DIR",
        help="output folder, as the other bench studies take; results.json is written there "
        "(default bench/results/voronoi_speed)",
    )
    args = parser.parse_args(argv)
    repeats = args.repeats or (3 if args.quick else 7)
    if args.device_one_pixel_child:
        pin_to_one_core()
        print(json.dumps(device_one_pixel(ONE_PIXEL_REPEAT_FACTOR * repeats, seed=11)))
        return
    machine_before = machine()
    rng = np.random.default_rng(7)
    rows = []
    # One 4096-sample pixel, then n = 64 ... 4096 over enough pixels for ~0.2 M samples.
    rows.append(measure(4096, 1, ONE_PIXEL_REPEAT_FACTOR * repeats, rng))
    for n in [64, 256, 1024, 4096]:
        pixels = 4 if args.quick else max(2, 200_000 // n)
        rows.append(measure(n, pixels, repeats, rng))
    # A batch of 4096 pixels (n = 64 in quick mode, 256 otherwise).
    rows.append(measure(64 if args.quick else 256, 256 if args.quick else 4096, repeats, rng))
    print(
        "CPU time (process_time), medians of the interleaved repeats of each row; "
        f"POINTS_PER_QHULL_CALL = {POINTS_PER_QHULL_CALL}"
    )
    print(
        "| n | pixels | repeats | Qhull calls | recomputed | stage ms/pixel | bare (same calls) | "
        "bare (per pixel) | stage/bare same | stage/bare per-pixel | us/sample | "
        "bare us/point |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['n']} | {r['pixels']} | {r['repeats']} | {r['qhull_calls']} | "
            f"{r['recomputed_pixels']} | "
            f"{r['stage_ms_per_pixel']:.3f} | {r['bare_same_calls_ms_per_pixel']:.3f} | "
            f"{r['bare_per_pixel_ms_per_pixel']:.3f} | {r['ratio_same_calls']:.3f} | "
            f"{r['ratio_per_pixel']:.3f} | {r['us_per_sample']:.2f} | "
            f"{r['bare_us_per_point']:.2f} |"
        )
    single = rows[0]
    print(
        f"one 4096-sample pixel with Qhull cells: {single['stage_ms_per_pixel']:.2f} ms "
        f"(bare Qhull alone on its {single['points']} points: "
        f"{single['bare_same_calls_ms_per_pixel']:.2f} ms, so no Qhull-based estimate reaches "
        f"the {TARGET_ONE_PIXEL_MS} ms target; the device cells below do)"
    )
    device = None if args.no_device else device_one_pixel_on_one_core(repeats)
    if device is not None:
        met_one = device["wall_ms"] <= TARGET_ONE_PIXEL_MS
        walls = device["wall_ms_per_process"]
        print(
            f"one 4096-sample pixel with device cells on one core ({device['device']}, "
            f"process pinned to one core, POCL_MAX_PTHREAD_COUNT=1): "
            f"{device['wall_ms']:.2f} ms wall, "
            f"{device['cpu_ms']:.2f} ms CPU: median over {device['processes']} processes "
            f"(each the median of {device['repeats']}; range {min(walls):.2f}-"
            f"{max(walls):.2f} ms wall) (target <= "
            f"{TARGET_ONE_PIXEL_MS} ms: {'met' if met_one else 'NOT met'}); "
            f"areas vs Qhull max relative difference "
            f"{device['max_relative_area_difference']:.1e}"
        )
    worst = max(rows, key=lambda r: r["ratio_same_calls"])
    met = all(r["ratio_same_calls"] <= TARGET_RATIO for r in rows)
    print(
        f"vor stage / bare Delaunay (same calls): worst {worst['ratio_same_calls']:.3f} at "
        f"n = {worst['n']}, {worst['pixels']} pixel(s); target <= {TARGET_RATIO} "
        f"{'met' if met else 'NOT met'} on every row"
    )
    results = {
        "clock": "process_time",
        "points_per_qhull_call": POINTS_PER_QHULL_CALL,
        "rows": rows,
        "device_one_pixel": device,
        "machine_before": machine_before,
        "machine_after": machine(),
    }
    write_json(args.out / "results.json", results)
    print(f"wrote {args.out / 'results.json'}")


if __name__ == "__main__":
    main()
