"""Tracing throughput: paths/s and rays/s on the shipped Cornell boxes.

    python bench/trace_throughput.py                       # 256 x 256, 64 spp, depth 8
    python bench/trace_throughput.py --scenes mitsuba-cbox --samplers uniform --repeats 5

For every scene and sampler: draw the sample sets once, trace once to warm up (PoCL compiles
a work-group function on the first launch), then time `repeats` traces and report medians.
Only the tracing kernel is timed (the sample sets are drawn before). Besides wall-clock rates
it records the process CPU time per trace: on a shared machine, cpu/wall well below the
device's compute-unit count means other processes were taking cores and the wall-clock figure
is pessimistic; `cpu_paths_per_s` = paths per CPU-second x compute units is the estimate for an
otherwise idle machine. Output: JSON (default bench/results/trace_throughput.json).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np

from clrender.runtime import create_runtime
from clrender.sampling import generate_sample_sets, make_sampler, tile_pixels
from clrender.scene import load_scene
from clrender.trace import PathTracer

SCENES = ("cornell-box", "cornell-box-glossy", "mitsuba-cbox")
SAMPLERS = ("uniform", "stratified", "sppp")
DEFAULT_OUTPUT = Path(__file__).resolve().parent / "results" / "trace_throughput.json"


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES))
    parser.add_argument("--samplers", nargs="+", default=list(SAMPLERS))
    parser.add_argument("--size", type=int, default=256, help="image width = height")
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--no-nee", action="store_true", help="BSDF sampling only (profiling)")
    parser.add_argument(
        "--russian-roulette",
        action="store_true",
        help="Russian roulette (ours starts after the second vertex, Mitsuba's at depth 5)",
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--device", default=None)
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT)
    return parser.parse_args(argv)


def time_traces(tracer, sets, seed, size, repeats):
    """Warm-up trace, then `repeats` timed traces: (wall seconds, cpu seconds, rays) each."""
    tracer.trace(sets, seed, size, size).wait()
    runs = []
    for _ in range(repeats):
        cpu0, wall0 = time.process_time(), time.perf_counter()
        result = tracer.trace(sets, seed, size, size)
        result.wait()
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        runs.append((wall, cpu, result.rays, result.nonfinite))
    return runs


def bench_one(runtime, scene_name, sampler, args):
    scene = load_scene(scene_name)
    tracer = PathTracer(
        runtime,
        scene,
        max_depth=args.max_depth,
        russian_roulette=args.russian_roulette,
        next_event_estimation=not args.no_nee,
    )
    pixels = tile_pixels(args.size, 0, 0, args.size, args.size)
    sets = generate_sample_sets(runtime, make_sampler(sampler, args.spp), args.seed, pixels)
    runs = time_traces(tracer, sets, args.seed, args.size, args.repeats)
    wall = statistics.median(r[0] for r in runs)
    cpu = statistics.median(r[1] for r in runs)
    paths = sets.traced_total
    units = runtime.device.max_compute_units
    return {
        "scene": scene_name,
        "sampler": sampler,
        "paths": paths,
        "rays": runs[-1][2],
        "nonfinite": runs[-1][3],
        "wall_s": wall,
        "cpu_s": cpu,
        "paths_per_s": paths / wall,
        "rays_per_s": runs[-1][2] / wall,
        "cpu_over_wall": cpu / wall,
        "cpu_paths_per_s": paths / cpu * units,
        "wall_s_all": [r[0] for r in runs],
    }


def main(argv=None):
    args = parse_args(argv)
    runtime = create_runtime(args.device)
    load_before = os.getloadavg()
    rows = []
    for scene_name in args.scenes:
        for sampler in args.samplers:
            row = bench_one(runtime, scene_name, sampler, args)
            rows.append(row)
            print(f"{scene_name:20s} {sampler:10s} {row['paths_per_s'] / 1e6:6.3f} M paths/s "
                  f"{row['rays_per_s'] / 1e6:6.2f} M rays/s  (cpu/wall {row['cpu_over_wall']:.2f},"
                  f" idle-machine estimate {row['cpu_paths_per_s'] / 1e6:.3f} M paths/s)",
                  flush=True)  # fmt: skip
    report = {
        "device": runtime.describe(),
        "compute_units": runtime.device.max_compute_units,
        "size": args.size,
        "spp": args.spp,
        "max_depth": args.max_depth,
        "next_event_estimation": not args.no_nee,
        "russian_roulette": args.russian_roulette,
        "repeats": args.repeats,
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(),
        "pocl_env": {k: v for k, v in os.environ.items() if k.startswith(("POCL", "PYOPENCL"))},
        "numpy": np.__version__,
        "results": rows,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(report, indent=1))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
