"""Estimators on the path-traced Cornell box: image MSE against a high-spp reference.

    python bench/render_estimators.py                   # 64 x 64, 64 spp, reference 4096 spp
    python bench/render_estimators.py --size 32 --seeds 1 2 3 4
    python bench/render_estimators.py --workers 2     # or --scheduler ADDRESS: on Dask

Takes the cached reference of bench/common.py (4 stratified mc parts, reference-spp in all,
rendered once and reused), then renders every (estimator, sampler) pair through the full
pipeline at the same spp for each seed, and reports the mean squared error over the image (all
channels), its per-seed values and standard error over the seeds, and the host (estimator)
time. This is how the render
command's default estimator was chosen. For MSE against wall time at several spp on both
Cornell boxes see bench/efficiency_study.py. Output: JSON (default
bench/results/render_estimators.json).

Where: every (pair, seed) render is one task (bench/common.py render_task), in this process by
default or on a Dask cluster (--workers N, --scheduler ADDRESS), each timed on the worker that
renders it; the MSEs are the same wherever they run, the host times are not (workers share
cores). A reference not yet cached is split over the cluster by pixel ranges (bit-identical).
The JSON records where the renders ran.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import numpy as np
from common import (
    RENDER_PAIRS,
    RESULTS,
    RenderTask,
    add_executor_options,
    executor_from_args,
    executor_record,
    image_errors,
    process_runtime,
    reference,
    render_tasks,
    write_json,
)
from figures import spread

PAIRS = [*RENDER_PAIRS, ("cvor", "stratified")]
DEFAULT_OUTPUT = RESULTS / "render_estimators.json"


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default="cornell-box")
    parser.add_argument("--size", type=int, default=64, help="image width = height")
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--reference-spp", type=int, default=4096)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT)
    add_executor_options(parser)
    return parser.parse_args(argv)


def main(argv=None) -> None:
    args = parse_args(argv)
    with executor_from_args(args) as executor:
        run(args, executor)


def run(args, executor) -> None:
    runtime = process_runtime()
    size = (args.size, args.size)
    ref, ref_var, ref_info = reference(
        runtime, args.scene, size, args.reference_spp, executor=executor
    )
    tasks = [
        RenderTask(args.scene, size, (estimator,), sampler, args.spp, seed)
        for estimator, sampler in PAIRS
        for seed in args.seeds
    ]
    done = iter(render_tasks(executor, tasks))
    rows = []
    for estimator, sampler in PAIRS:
        renders = [next(done) for _ in args.seeds]
        mses = spread(
            [
                image_errors(images[estimator].astype(np.float64), ref, ref_var)["mse"]
                for images, _ in renders
            ]
        )
        host = statistics.mean(row["host_s"] for _, row in renders)
        rows.append(
            {
                "estimator": estimator,
                "sampler": sampler,
                "mse": mses["mean"],
                "mse_se": mses["se"],
                "seeds": args.seeds,
                "mse_per_seed": mses["values"],
                "host_s": host,
                "workers": sorted({row["worker"] for _, row in renders}),
            }
        )
        print(
            f"{estimator:8s} {sampler:10s} MSE {mses['mean']:.5f} +- {mses['se']:.1g} "
            f"({', '.join(f'{m:.5f}' for m in mses['values'])})  host {host:.2f} s",
            flush=True,
        )
    write_json(
        args.output,
        {
            "settings": {k: str(v) for k, v in vars(args).items()},
            "device": runtime.describe(),
            "executor": executor_record(executor, args),
            "reference": ref_info,
            "rows": rows,
        },
    )
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
