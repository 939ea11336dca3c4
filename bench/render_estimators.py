"""Estimators on the path-traced Cornell box: image MSE against a high-spp reference.

    python bench/render_estimators.py                   # 64 x 64, 64 spp, reference 4096 spp
    python bench/render_estimators.py --size 32 --seeds 1 2 3 4

Takes the cached reference of bench/common.py (4 stratified mc parts, reference-spp in all,
rendered once and reused), then renders every (estimator, sampler) pair through the full
pipeline at the same spp for each seed, and reports the mean squared error over the image (all
channels), its per-seed values and standard error over the seeds, and the host (estimator)
time. This is how the render
command's default estimator was chosen. For MSE against wall time at several spp on both
Cornell boxes see bench/efficiency_study.py. Output: JSON (default
bench/results/render_estimators.json).
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from common import (
    RENDER_PAIRS,
    RESULTS,
    image_errors,
    make_source,
    reference,
    timed_render,
    write_json,
)
from figures import spread

from clrender.runtime import create_runtime

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
    return parser.parse_args(argv)


def main(argv=None) -> None:
    args = parse_args(argv)
    runtime = create_runtime()
    ref, ref_var, ref_info = reference(
        runtime, args.scene, (args.size, args.size), args.reference_spp
    )
    source = make_source(runtime, args.scene, args.size, args.size)
    rows = []
    for estimator, sampler in PAIRS:
        renders = [
            timed_render(runtime, source, estimator, sampler, args.spp, seed) for seed in args.seeds
        ]
        mses = spread([image_errors(image, ref, ref_var)["mse"] for image, _ in renders])
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
            }
        )
        print(
            f"{estimator:8s} {sampler:10s} MSE {mses['mean']:.5f} +- {mses['se']:.1g} "
            f"({', '.join(f'{m:.5f}' for m in mses)})  host {host:.2f} s",
            flush=True,
        )
    write_json(
        args.output,
        {
            "settings": {k: str(v) for k, v in vars(args).items()},
            "device": runtime.describe(),
            "reference": ref_info,
            "rows": rows,
        },
    )
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
