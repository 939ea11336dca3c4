"""Tracing throughput: paths/s and rays/s on the shipped Cornell boxes.

    python bench/trace_throughput.py                       # 256 x 256, 64 spp, depth 8
    python bench/trace_throughput.py --scenes mitsuba-cbox --samplers independent --repeats 5
    python bench/trace_throughput.py --profile --samplers independent --spp 16   # where time goes

For every scene and sampler: draw the sample sets once, trace once to warm up (PoCL compiles
a work-group function on the first launch), then time `repeats` traces and report medians.
Only the tracing kernel is timed (the sample sets are drawn before). Besides wall-clock rates
it records the process CPU time per trace: on a shared machine, cpu/wall well below the
device's compute-unit count means other processes were taking cores and the wall-clock figure
is pessimistic; `cpu_paths_per_s` = paths per CPU-second x compute units is the estimate for an
otherwise idle machine. Output: JSON (default bench/results/trace_throughput.json).

--profile adds, per scene (first sampler), the variants the optimisation work used: depth 0
(camera rays only), depth 1, depth 8 without NEE, and depth 8 with shadow rays counted but not
traced (a profiling build, PROFILE_SKIP_SHADOW_RAYS); it prints CPU ns per path for each and
derived costs (per shadow ray traced, per bounce vertex, per camera ray).

--trace-kernel megakernel simd compares the tracing kernels (clrender.trace TRACE_KERNELS, the
same radiance to the bit) on the same sample sets: after a warm-up launch of each, round after
round each kernel once in turn (at least 5 rounds: --repeats), medians of wall and CPU time
(time.process_time: PoCL's threads run in this process) per kernel, and per round the ratio of
each kernel's paths per CPU-second to the first kernel's; the table prints the median ratio and
its range. A scene named mesh-sphere-N is mitsuba-cbox with a tessellated sphere of about N
triangles (bench/bvh_scaling.py; a BVH from 64 triangles on).

    python bench/trace_throughput.py --samplers independent --trace-kernel megakernel simd \
        --scenes mitsuba-cbox cornell-box cornell-box-glossy veach-mis mesh-sphere-20000
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
from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import load_scene
from clrender.trace import TRACE_KERNELS, PathTracer

SCENES = ("cornell-box", "cornell-box-glossy", "mitsuba-cbox")
SAMPLERS = ("independent", "stratified", "sobol", "zsobol", "sppp", "sppp-sobol")
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
    parser.add_argument(
        "--trace-kernel",
        nargs="+",
        default=["megakernel"],
        choices=list(TRACE_KERNELS),
        help="tracing kernel(s); several: compared in alternating rounds (see above)",
    )
    parser.add_argument(
        "--profile", action="store_true", help="also time the profile variants (see above)"
    )
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


MESH_SCENE_PREFIX = "mesh-sphere-"


def bench_scene(scene_name):
    """A shipped scene by name, or mesh-sphere-N: mitsuba-cbox with a sphere of about N
    triangles (bench/bvh_scaling.py)."""
    if scene_name.startswith(MESH_SCENE_PREFIX):
        from bvh_scaling import scene_with_sphere_mesh

        return scene_with_sphere_mesh(int(scene_name[len(MESH_SCENE_PREFIX) :]))
    return load_scene(scene_name)


def make_tracer(runtime, scene, args, max_depth=None, nee=None, defines=None, kernel=None):
    return PathTracer(
        runtime,
        scene,
        max_depth=args.max_depth if max_depth is None else max_depth,
        russian_roulette=args.russian_roulette,
        next_event_estimation=(not args.no_nee) if nee is None else nee,
        profile_defines=defines,
        trace_kernel=kernel or args.trace_kernel[0],
    )


def bench_one(runtime, scene_name, sampler, args, max_depth=None, nee=None, defines=None):
    scene = bench_scene(scene_name)
    tracer = make_tracer(runtime, scene, args, max_depth, nee, defines)
    pixels = rectangle_pixels(args.size, 0, 0, args.size, args.size)
    size = (args.size, args.size)
    config = make_sampler(sampler, args.spp)
    sets = generate_sample_sets(runtime, config, args.seed, pixels, None, size)
    runs = time_traces(tracer, sets, args.seed, args.size, args.repeats)
    wall = statistics.median(r[0] for r in runs)
    cpu = statistics.median(r[1] for r in runs)
    paths = sets.traced_total
    rays = runs[-1][2]
    units = runtime.device.max_compute_units
    return {
        "scene": scene_name,
        "sampler": sampler,
        "max_depth": tracer.max_depth,
        "next_event_estimation": tracer.next_event_estimation,
        "defines": defines or {},
        "paths": paths,
        "rays": rays,
        "rays_per_path": rays / paths,
        "nonfinite": runs[-1][3],
        "wall_s": wall,
        "cpu_s": cpu,
        "paths_per_s": paths / wall,
        "rays_per_s": rays / wall,
        "cpu_over_wall": cpu / wall,
        "cpu_paths_per_s": paths / cpu * units,
        "cpu_rays_per_s": rays / cpu * units,
        "cpu_ns_per_path": cpu / paths * 1e9,
        "wall_s_all": [r[0] for r in runs],
        "cpu_s_all": [r[1] for r in runs],
        "trace_kernel": tracer.trace_kernel,
    }


def compare_kernels(runtime, scene_name, sampler, args):
    """The tracing kernels of --trace-kernel on the same sample sets, one launch each in turn
    round after round (after a warm-up launch each): medians, and per round each kernel's paths
    per CPU-second over the first kernel's."""
    scene = bench_scene(scene_name)
    tracers = {
        kernel: make_tracer(runtime, scene, args, kernel=kernel) for kernel in args.trace_kernel
    }
    pixels = rectangle_pixels(args.size, 0, 0, args.size, args.size)
    size = (args.size, args.size)
    sets = generate_sample_sets(
        runtime, make_sampler(sampler, args.spp), args.seed, pixels, None, size
    )
    paths = sets.traced_total
    first = {kernel: tracer.trace(sets, args.seed, *size) for kernel, tracer in tracers.items()}
    reference = next(iter(first.values()))
    radiance = reference.to_host()
    bit_equal = {kernel: bool(np.array_equal(r.to_host(), radiance)) for kernel, r in first.items()}
    runs = {kernel: [] for kernel in tracers}
    loads = []
    for _ in range(max(5, args.repeats)):
        loads.append(os.getloadavg()[0])
        for kernel, tracer in tracers.items():
            cpu0, wall0 = time.process_time(), time.perf_counter()
            tracer.trace(sets, args.seed, *size).wait()
            runs[kernel].append((time.perf_counter() - wall0, time.process_time() - cpu0))
    base = args.trace_kernel[0]
    kernels = {}
    for kernel, timings in runs.items():
        wall = statistics.median(w for w, _ in timings)
        cpu = statistics.median(c for _, c in timings)
        ratios = [b[1] / c for (_, c), b in zip(timings, runs[base], strict=True)]
        wall_ratios = [b[0] / w for (w, _), b in zip(timings, runs[base], strict=True)]
        kernels[kernel] = {
            "wall_s": wall,
            "cpu_s": cpu,
            "paths_per_s": paths / wall,
            "paths_per_cpu_s": paths / cpu,
            "cpu_over_wall": cpu / wall,
            "bit_equal_to_first": bit_equal[kernel],
            "rays": first[kernel].rays,
            f"cpu_ratio_to_{base}_per_round": ratios,
            f"median_cpu_ratio_to_{base}": statistics.median(ratios),
            f"median_wall_ratio_to_{base}": statistics.median(wall_ratios),
            "wall_s_all": [w for w, _ in timings],
            "cpu_s_all": [c for _, c in timings],
        }
    return {
        "scene": scene_name,
        "sampler": sampler,
        "paths": paths,
        "rays_per_path": reference.rays / paths,
        "loadavg_per_round": loads,
        "kernels": kernels,
    }


def print_comparison(row, base):
    for kernel, k in row["kernels"].items():
        r = k[f"cpu_ratio_to_{base}_per_round"]
        cpu_ratio = k[f"median_cpu_ratio_to_{base}"]
        wall_ratio = k[f"median_wall_ratio_to_{base}"]
        print(
            f"{row['scene']:20s} {row['sampler']:12s} {kernel:10s} "
            f"{k['paths_per_cpu_s'] / 1e6:6.3f} M paths/CPU-s {k['paths_per_s'] / 1e6:6.3f} M "
            f"paths/s wall | cpu/wall {k['cpu_over_wall']:.2f} | x{cpu_ratio:.2f} per CPU-s "
            f"(rounds {min(r):.2f}-{max(r):.2f}), x{wall_ratio:.2f} wall | "
            f"bit-equal {k['bit_equal_to_first']}",
            flush=True,
        )


def print_row(row, label):
    print(
        f"{row['scene']:20s} {label:28s} wall {row['paths_per_s'] / 1e6:6.3f} M paths/s "
        f"{row['rays_per_s'] / 1e6:6.2f} M rays/s | cpu/wall {row['cpu_over_wall']:.2f} | "
        f"CPU-time estimate {row['cpu_paths_per_s'] / 1e6:6.3f} M paths/s "
        f"{row['cpu_rays_per_s'] / 1e6:6.2f} M rays/s ({row['rays_per_path']:.2f} rays/path, "
        f"{row['cpu_ns_per_path']:.0f} CPU ns/path)",
        flush=True,
    )


PROFILE_VARIANTS = {
    # name: (max_depth, next_event_estimation, kernel defines)
    "depth0": (0, True, None),
    "depth1": (1, True, None),
    "no_nee": (None, False, None),
    "shadow_rays_untraced": (None, True, {"PROFILE_SKIP_SHADOW_RAYS": True}),
}


def profile_scene(runtime, scene_name, sampler, args, full):
    """The profile variants of one scene and the costs derived from them (CPU ns)."""
    rows = {"full": full}
    for name, (depth, nee, defines) in PROFILE_VARIANTS.items():
        rows[name] = bench_one(runtime, scene_name, sampler, args, depth, nee, defines)
        print_row(rows[name], f"{sampler} {name}")
    ns = {name: row["cpu_ns_per_path"] for name, row in rows.items()}
    shadow_rays = full["rays_per_path"] - rows["no_nee"]["rays_per_path"]
    bounce_rays = rows["no_nee"]["rays_per_path"] - 1.0
    derived = {
        "cpu_ns_per_path": ns,
        "shadow_rays_per_path": shadow_rays,
        "camera_ray_ns": ns["depth0"],
        # NEE (light sample, BSDF eval, shadow ray) per shadow ray; and its ray query alone
        "nee_ns_per_shadow_ray": (ns["full"] - ns["no_nee"]) / max(shadow_rays, 1e-9),
        "shadow_query_ns_per_shadow_ray": (ns["full"] - ns["shadow_rays_untraced"])
        / max(shadow_rays, 1e-9),
        # BSDF sampling, two Philox draws and the closest-hit query, per bounce (no NEE)
        "bounce_ns_per_vertex": (ns["no_nee"] - ns["depth0"]) / max(bounce_rays, 1e-9),
    }
    print(
        f"{scene_name:20s} profile: camera ray {derived['camera_ray_ns']:.0f} ns; per bounce "
        f"vertex {derived['bounce_ns_per_vertex']:.0f} ns; per shadow ray: NEE "
        f"{derived['nee_ns_per_shadow_ray']:.0f} ns of which the occlusion query "
        f"{derived['shadow_query_ns_per_shadow_ray']:.0f} ns (CPU ns)",
        flush=True,
    )
    return {"variants": list(rows.values())[1:], "derived": derived}


def main(argv=None):
    args = parse_args(argv)
    runtime = create_runtime(args.device)
    load_before = os.getloadavg()
    rows = []
    profiles = {}
    comparisons = []
    for scene_name in args.scenes:
        for sampler in args.samplers:
            if len(args.trace_kernel) > 1:
                comparisons.append(compare_kernels(runtime, scene_name, sampler, args))
                print_comparison(comparisons[-1], args.trace_kernel[0])
                continue
            row = bench_one(runtime, scene_name, sampler, args)
            rows.append(row)
            print_row(row, sampler)
        if args.profile and len(args.trace_kernel) == 1:
            profiles[scene_name] = profile_scene(
                runtime, scene_name, args.samplers[0], args, rows[-len(args.samplers)]
            )
    report = {
        "device": runtime.describe(),
        "platform": runtime.device.platform.version,
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
        "trace_kernels": args.trace_kernel,
        "results": rows,
        "kernel_comparisons": comparisons,
        "profile": profiles,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(report, indent=1))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
