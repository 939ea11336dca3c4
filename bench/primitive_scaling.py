"""How brute-force intersection scales: rays/s against the number of quads.

    python bench/primitive_scaling.py [--counts 18 34 66 130 258 514] [--size 64] [--spp 16]

Mitsuba's Cornell box plus K small random diffuse quads inside it (K = count - 18), traced at
depth 8. Every ray tests every quad (8 per vector test), so the cost per ray grows linearly;
the figures say up to which primitive count brute force is still acceptable. Rates are
per CPU-second x compute units (see trace_throughput.py), robust to a shared machine.
Output: JSON (default bench/results/primitive_scaling.json).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from common import machine

from clrender.runtime import create_runtime
from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import load_scene
from clrender.trace import PathTracer

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "results" / "primitive_scaling.json"


def scene_with_extra_quads(extra: int, seed: int, folder: Path):
    """mitsuba-cbox.toml plus `extra` random quads of side 0.05 inside the box."""
    base = load_scene("mitsuba-cbox")
    rng = np.random.default_rng(seed)
    text = base.path.read_text()
    for _ in range(extra):
        corner = rng.uniform(-0.9, 0.9, 3)
        edge1, edge2 = rng.normal(size=(2, 3)) * 0.05
        text += (
            f'\n[[shapes]]\ntype = "quad"\ncorner = {corner.tolist()}\n'
            f'edge1 = {edge1.tolist()}\nedge2 = {edge2.tolist()}\nmaterial = "white"\n'
        )
    path = folder / f"scaling-{extra}.toml"
    path.write_text(text)
    return load_scene(path)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[18, 34, 66, 130, 258, 514])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT)
    args = parser.parse_args(argv)
    runtime = create_runtime()
    before = machine()
    units = runtime.device.max_compute_units
    pixels = rectangle_pixels(args.size, 0, 0, args.size, args.size)
    sets = generate_sample_sets(runtime, make_sampler("independent", args.spp), 1, pixels)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for count in args.counts:
            scene = scene_with_extra_quads(count - 18, 7, Path(folder))
            # Brute force at every count (the renderer switches to the BVH past about 200
            # quads: bench/bvh_scaling.py compares the two)
            tracer = PathTracer(runtime, scene, max_depth=8, brute_force_limit=2**62)
            tracer.trace(sets, 1, args.size, args.size).wait()
            cpu_times, rays = [], 0
            for _ in range(args.repeats):
                cpu0 = time.process_time()
                result = tracer.trace(sets, 1, args.size, args.size)
                result.wait()
                cpu_times.append(time.process_time() - cpu0)
                rays = result.rays
            cpu = statistics.median(cpu_times)
            row = {
                "quads": len(scene.quads),
                "rays": rays,
                "cpu_s": cpu,
                "rays_per_s": rays / cpu * units,
                "paths_per_s": sets.traced_total / cpu * units,
            }
            rows.append(row)
            print(
                f"{row['quads']:5d} quads: {row['rays_per_s'] / 1e6:7.2f} M rays/s "
                f"{row['paths_per_s'] / 1e6:6.3f} M paths/s",
                flush=True,
            )
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(
        json.dumps(
            {
                "device": runtime.describe(),
                "machine_before": before,
                "machine_after": machine(),
                "results": rows,
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
