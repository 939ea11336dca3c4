"""Render pipeline overlap: device, host and wall time with and without overlap.

    python bench/render_overlap.py        # the default render: Cornell box 128^2, 64 spp
    python bench/render_overlap.py --estimator ivor_sn --repeats 5

Runs the full pipeline (sample sets -> path tracer -> host estimator -> film) alternately with
and without overlap after a warm-up render, and reports medians of: device time (main thread
waiting on sample sets, tracing and downloads), host time (estimator stage), wall time, and the
process CPU time. With overlap the wall time should approach max(device, host); on a CPU OpenCL
device the two stages share the cores, so each stage's own time grows when they overlap.
The 1-minute load average is recorded: other processes taking cores inflate every figure.
Output: JSON (default bench/results/render_overlap.json).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from clrender.pipeline import RenderSettings, render
from clrender.radiance import PathTracerSource
from clrender.runtime import create_runtime
from clrender.sampling import make_sampler
from clrender.scene import load_scene
from clrender.trace import PathTracer

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "results" / "render_overlap.json"


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default="cornell-box")
    parser.add_argument("--size", type=int, default=128, help="image width = height")
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--sampler", default="sppp")
    parser.add_argument("--estimator", default="vor_sn")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT)
    return parser.parse_args(argv)


def timed_render(runtime, source, args, overlap: bool) -> dict:
    settings = RenderSettings(
        args.size,
        args.size,
        make_sampler(args.sampler, args.spp),
        args.estimator,
        seed=1,
        overlap=overlap,
    )
    cpu = time.process_time()
    stats = render(runtime, source, settings).stats
    return {
        "overlap": overlap,
        "wall_s": stats.wall_seconds,
        "device_s": stats.device_seconds,
        "host_s": stats.host_seconds,
        "cpu_s": time.process_time() - cpu,
        "load_1min": os.getloadavg()[0],
    }


def medians(runs: list[dict]) -> dict:
    keys = ["wall_s", "device_s", "host_s", "cpu_s", "load_1min"]
    return {key: statistics.median(run[key] for run in runs) for key in keys}


def main(argv=None) -> None:
    args = parse_args(argv)
    runtime = create_runtime()
    tracer = PathTracer(runtime, load_scene(args.scene), max_depth=8)
    source = PathTracerSource(tracer, args.size, args.size)
    timed_render(runtime, source, args, overlap=False)  # warm-up: kernel builds, work-groups
    runs = [
        timed_render(runtime, source, args, overlap)
        for _ in range(args.repeats)
        for overlap in (True, False)
    ]
    summary = {
        mode: medians([r for r in runs if r["overlap"] == (mode == "overlap")])
        for mode in ("overlap", "sequential")
    }
    result = {
        "settings": {k: str(v) for k, v in vars(args).items()},
        "device": runtime.describe(),
        "runs": runs,
        "median": summary,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2))
    print(
        f"{args.scene} {args.size}^2, {args.spp} spp, {args.sampler} + {args.estimator}, "
        f"{args.repeats} repeats (medians):"
    )
    for mode, row in summary.items():
        print(
            f"  {mode:10s} wall {row['wall_s']:6.2f} s  device {row['device_s']:6.2f} s  "
            f"host {row['host_s']:6.2f} s  cpu {row['cpu_s']:6.2f} s  "
            f"load {row['load_1min']:.1f}"
        )
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
