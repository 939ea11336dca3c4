"""How the BVH scales: rays/s against triangle count, BVH build time, and small meshes, the
Cornell boxes and the quad scenes of primitive_scaling.py traced with and without the BVH.

    python bench/bvh_scaling.py [--triangles 20 1000 10000 100000 1000000] [--size 64]
                                [--spp 16] [--repeats 3] [--skip-render]
    python bench/bvh_scaling.py --paired-rounds 20 --triangles 100000 --size 128 --skip-render

--paired-rounds N traces, round after round, mitsuba-cbox and cornell-box (brute force) and the
sphere mesh of each --triangles count in the same process, and reports the median and range
over rounds of each mesh's rate against each box's in the same round (issue 15's target: 100 000
triangles at no less than half the rays/s of the 18-quad mitsuba-cbox, the base of
primitive_scaling.py): a ratio from one stretch of machine load, not two.

Triangles: a sphere of radius 0.5 tessellated in latitude/longitude (two triangles per cell,
none at the poles' degenerate corners) at the centre of Mitsuba's Cornell box, traced at depth 8
as the renderer chooses (BVH or brute force: scene_device.BRUTE_FORCE_LIMIT). Build: the whole way
from the scene's primitives to what the device receives (scene_device.pack_bvh's steps:
primitive_bounds, clrender.bvh's binary build and its collapse to 8-wide nodes, the leaf records
of pack_bvh_leaves), each step's CPU and wall time and minor page faults and their total,
medians of --repeats (all in one process: the first repeat pays for fresh memory); the binary
tree's SAH cost (clrender.bvh.sah_cost), the 8-wide tree's node count, lanes used a node and
cost (clrender.bvh.wide_sah_cost). Small meshes, Cornell boxes and quad scenes: the same launch
by brute force and through the BVH, alternating, so the two rates come from the same stretch of
machine load (a scene of at most BVH_MAX_BRUTE_QUADS quads alone, as the Cornell boxes, has no
BVH: both launches are brute force, and their ratio shows the noise). Rates are per CPU-second
x compute units (as trace_throughput.py), robust to a shared machine.
Output: JSON (default bench/results/bvh_scaling.json).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from common import machine
from primitive_scaling import scene_with_extra_quads

from clrender.bvh import build_bvh, collapse_bvh, sah_cost, wide_sah_cost
from clrender.runtime import create_runtime
from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import load_scene
from clrender.scene_device import (
    BRUTE_FORCE_LIMIT,
    BVH_MAX_BRUTE_QUADS,
    brute_force_cost,
    pack_bvh_leaves,
    pack_triangles,
    primitive_bounds,
)
from clrender.trace import PathTracer

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "results" / "bvh_scaling.json"
FORCE_BVH = -1  # brute_force_limit that builds a BVH for every scene
NEVER_BVH = 2**62  # brute_force_limit that keeps brute force for every scene


def sphere_mesh(triangles: int, radius: float = 0.5) -> dict:
    """A latitude/longitude sphere of about `triangles` triangles (counter-clockwise seen from
    outside), as pack_triangles' input."""
    rings = max(2, round(math.sqrt(triangles / 4.0)) + 1)
    segments = max(3, round(triangles / (2.0 * (rings - 1))))
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)[:-1]
    t, p = np.meshgrid(theta, phi, indexing="ij")
    positions = radius * np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1)
    positions = positions.reshape(-1, 3)
    ring = np.arange(rings)[:, None] * segments
    a = ring + np.arange(segments)[None, :]
    b = ring + (np.arange(segments)[None, :] + 1) % segments
    c, d = a + segments, b + segments
    first = np.stack([a, b, d], -1)[1:].reshape(-1, 3)  # none at the north pole
    second = np.stack([a, d, c], -1)[:-1].reshape(-1, 3)  # none at the south pole
    indices = np.concatenate([first, second])
    return {"positions": positions, "indices": indices, "normals": None, "material": 0}


def scene_with_sphere_mesh(triangles: int):
    """mitsuba-cbox plus a tessellated sphere (white) at its centre."""
    base = load_scene("mitsuba-cbox")
    packed, normals = pack_triangles([sphere_mesh(triangles)])
    return dataclasses.replace(base, triangles=packed, triangle_normals=normals)


def rays_per_second(runtime, tracer, sets, size, repeats):
    tracer.trace(sets, 1, size, size).wait()
    cpu_times, walls, rays = [], [], 0
    for _ in range(repeats):
        cpu0, wall0 = time.process_time(), time.perf_counter()
        result = tracer.trace(sets, 1, size, size)
        result.wait()
        cpu_times.append(time.process_time() - cpu0)
        walls.append(time.perf_counter() - wall0)
        rays = result.rays
    cpu = statistics.median(cpu_times)
    units = runtime.device.max_compute_units
    return {
        "rays": rays,
        "cpu_s": cpu,
        "wall_s": statistics.median(walls),
        "rays_per_s": rays / cpu * units,
    }


def build_times(scene, repeats):
    """The whole way from the scene's primitives to what the device receives, as
    scene_device.pack_bvh takes it, stage by stage (CPU and wall time, medians of `repeats`):
    primitive_bounds, build_bvh (the binary tree), collapse_bvh (8-wide nodes) and
    pack_bvh_leaves (the leaf records), and the minor page faults of each (first touches of
    fresh memory: about 5 us each on this machine); and the binary tree's SAH cost."""
    stages = ("bounds", "build", "collapse", "leaves")
    measures = {"cpu_s": 0, "wall_s": 1, "page_faults": 2}
    samples = {(stage, name): [] for stage in (*stages, "total_build") for name in measures}

    def mark():
        usage = resource.getrusage(resource.RUSAGE_SELF)
        return time.process_time(), time.perf_counter(), usage.ru_minflt

    # As pack_bvh: at most BVH_MAX_BRUTE_QUADS quads stay out of the tree
    first = len(scene.quads) if len(scene.quads) <= BVH_MAX_BRUTE_QUADS else 0
    for _ in range(repeats):
        marks = [mark()]
        lower, upper = primitive_bounds(scene.quads, scene.spheres, scene.triangles)
        marks.append(mark())
        binary, prims = build_bvh(lower[first:], upper[first:])
        prims += np.uint32(first)
        marks.append(mark())
        wide = collapse_bvh(binary)
        marks.append(mark())
        pack_bvh_leaves(wide, prims, scene.quads, len(scene.spheres), scene.triangles)
        marks.append(mark())
        spans = [*zip(stages, marks[:-1], marks[1:], strict=True)]
        spans.append(("total_build", marks[0], marks[-1]))
        for stage, before, after in spans:
            for name, k in measures.items():
                samples[stage, name].append(after[k] - before[k])
    row = {
        f"{stage}_{name}": statistics.median(values) for (stage, name), values in samples.items()
    }
    lanes = (wide["count"] >= 0).sum(axis=1)
    return {
        **row,
        "nodes": len(binary),
        "sah_cost": sah_cost(binary),
        "wide_nodes": len(wide),
        "wide_lanes_used": float(lanes.mean()) if len(wide) else 0.0,
        "wide_sah_cost": wide_sah_cost(wide),
    }


def compare(runtime, scene, sets, size, repeats, label):
    """Brute force and the BVH, alternating; and which of the two the renderer picks."""
    tracers = {
        "brute": PathTracer(runtime, scene, max_depth=8, brute_force_limit=NEVER_BVH),
        "bvh": PathTracer(runtime, scene, max_depth=8, brute_force_limit=FORCE_BVH),
    }
    rates = {name: [] for name in tracers}
    for _ in range(repeats):
        for name, tracer in tracers.items():
            rates[name].append(rays_per_second(runtime, tracer, sets, size, 1)["rays_per_s"])
    row = {
        "scene": label,
        "primitives": scene.primitive_count,
        "default_uses_bvh": brute_force_cost(
            len(scene.quads), len(scene.spheres), len(scene.triangles)
        )
        > BRUTE_FORCE_LIMIT,
    }
    for name in tracers:
        row[f"{name}_rays_per_s"] = statistics.median(rates[name])
    row["bvh_over_brute"] = row["bvh_rays_per_s"] / row["brute_rays_per_s"]
    print(
        f"{label:>22s} ({row['primitives']:6d} prims): brute force "
        f"{row['brute_rays_per_s'] / 1e6:6.2f} M rays/s, BVH "
        f"{row['bvh_rays_per_s'] / 1e6:6.2f} M rays/s (x{row['bvh_over_brute']:.2f})",
        flush=True,
    )
    return row


def paired_ratios(runtime, sets, size, rounds, triangle_counts):
    """Rays/s of each sphere mesh against mitsuba-cbox's and cornell-box's, traced in turn round
    after round: per mesh and box, the median, lowest and highest ratio within a round."""
    scenes = {name: load_scene(name) for name in ("mitsuba-cbox", "cornell-box")}
    meshes = {count: scene_with_sphere_mesh(count) for count in triangle_counts}
    tracers = {name: PathTracer(runtime, scene, max_depth=8) for name, scene in scenes.items()}
    for count, mesh in meshes.items():
        tracers[count] = PathTracer(runtime, mesh, max_depth=8)
    rates = {key: [] for key in tracers}
    for tracer in tracers.values():  # warm: kernels built, buffers touched
        rays_per_second(runtime, tracer, sets, size, 1)
    for _ in range(rounds):
        for key, tracer in tracers.items():
            rates[key].append(rays_per_second(runtime, tracer, sets, size, 1)["rays_per_s"])
    rows = []
    for count, mesh in meshes.items():
        row = {"triangles": len(mesh.triangles), "rounds": rounds}
        row["rays_per_s"] = statistics.median(rates[count])
        for name in scenes:
            ratios = sorted(a / b for a, b in zip(rates[count], rates[name], strict=True))
            row[f"{name}_rays_per_s"] = statistics.median(rates[name])
            row[f"against_{name}"] = statistics.median(ratios)
            row[f"against_{name}_range"] = [ratios[0], ratios[-1]]
        rows.append(row)
        print(
            f"{row['triangles']:8d} triangles against mitsuba-cbox: median "
            f"{row['against_mitsuba-cbox']:.3f}x (range {row['against_mitsuba-cbox_range'][0]:.3f}-"
            f"{row['against_mitsuba-cbox_range'][1]:.3f}, "
            f"{rounds} rounds) -- against cornell-box: median {row['against_cornell-box']:.3f}x "
            f"(range {row['against_cornell-box_range'][0]:.3f}-"
            f"{row['against_cornell-box_range'][1]:.3f})",
            flush=True,
        )
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--triangles", type=int, nargs="+", default=[20, 1000, 10000, 100000, 1000000]
    )
    parser.add_argument("--quads", type=int, nargs="+", default=[34, 66, 130, 258, 514])
    parser.add_argument(
        "--compare-triangles",
        type=int,
        nargs="+",
        default=[8, 20, 50, 100],
        help="sphere meshes traced both by brute force and through the BVH",
    )
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--skip-render", action="store_true", help="no traces but those of --paired-rounds"
    )
    parser.add_argument(
        "--paired-rounds",
        type=int,
        default=0,
        help="rounds of the meshes traced in turn with the Cornell boxes (rate ratios per round)",
    )
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT)
    args = parser.parse_args(argv)
    runtime = create_runtime()
    pixels = rectangle_pixels(args.size, 0, 0, args.size, args.size)
    sets = generate_sample_sets(runtime, make_sampler("independent", args.spp), 1, pixels)
    out = {
        "device": runtime.describe(),
        "brute_force_limit": BRUTE_FORCE_LIMIT,
        "size": args.size,
        "spp": args.spp,
        "machine_before": machine(),
        "triangles": [],
        "paired": [],
        "meshes": [],
        "cornell": [],
        "quads": [],
    }
    for count in args.triangles:
        scene = scene_with_sphere_mesh(count)
        row = {"triangles": len(scene.triangles), **build_times(scene, args.repeats)}
        if not args.skip_render:
            tracer = PathTracer(runtime, scene, max_depth=8)
            row.update(rays_per_second(runtime, tracer, sets, args.size, args.repeats))
        out["triangles"].append(row)
        rate = f"{row['rays_per_s'] / 1e6:6.2f} M rays/s" if "rays_per_s" in row else ""
        print(
            f"{row['triangles']:8d} triangles: CPU s bounds {row['bounds_cpu_s']:.3f}, binary "
            f"build {row['build_cpu_s']:.3f}, collapse {row['collapse_cpu_s']:.3f}, leaf records "
            f"{row['leaves_cpu_s']:.3f}; the whole way {row['total_build_cpu_s']:.3f} s CPU "
            f"{row['total_build_wall_s']:.3f} s wall, {row['total_build_page_faults']:.0f} page "
            f"faults; SAH cost {row['sah_cost']:6.2f}; 8-wide: {row['wide_nodes']} nodes, "
            f"{row['wide_lanes_used']:.1f} lanes used, cost {row['wide_sah_cost']:.2f}  {rate}",
            flush=True,
        )
    if not args.skip_render:
        for count in args.compare_triangles:
            scene = scene_with_sphere_mesh(count)
            label = f"{len(scene.triangles)} triangles"
            out["meshes"].append(compare(runtime, scene, sets, args.size, args.repeats, label))
        for name in ("cornell-box", "mitsuba-cbox", "cornell-box-glossy"):
            out["cornell"].append(
                compare(runtime, load_scene(name), sets, args.size, args.repeats, name)
            )
        with tempfile.TemporaryDirectory() as folder:
            for count in args.quads:
                scene = scene_with_extra_quads(count - 18, 7, Path(folder))
                out["quads"].append(
                    compare(runtime, scene, sets, args.size, args.repeats, f"{count} quads")
                )
    if args.paired_rounds > 0:
        out["paired"] = paired_ratios(runtime, sets, args.size, args.paired_rounds, args.triangles)
    out["machine_after"] = machine()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(out, indent=1))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
