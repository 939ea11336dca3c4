"""Estimators on the path-traced Cornell box: image MSE against a high-spp reference.

    python bench/render_estimators.py                   # 64 x 64, 64 spp, reference 4096 spp
    python bench/render_estimators.py --size 32 --seeds 1 2 3 4

Renders the reference once with mc over stratified samples, then every (estimator, sampler)
pair through the full pipeline at the same spp for each seed, and reports the mean squared
error over the image (all channels), its per-seed values, and the host (estimator) time.
This is how the render command's default estimator was chosen. Output: JSON (default
bench/results/render_estimators.json).
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

import numpy as np

from clrender.radiance import PathTracerSource
from clrender.render import RenderSettings, render
from clrender.runtime import create_runtime
from clrender.sampling import make_sampler
from clrender.scene import load_scene
from clrender.trace import PathTracer

PAIRS = [("mc", "uniform"), ("mc", "stratified"), ("mc_n", "sppp"), ("vor", "sppp"),
         ("vor_sn", "sppp"), ("fvor", "sppp"), ("ivor", "sppp"), ("ivor_sn", "sppp"),
         ("cvor", "uniform"), ("pvor", "uniform"), ("cvor", "stratified")]  # fmt: skip
DEFAULT_OUTPUT = Path(__file__).resolve().parent / "results" / "render_estimators.json"


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
    tracer = PathTracer(runtime, load_scene(args.scene), max_depth=8)
    source = PathTracerSource(tracer, args.size, args.size)

    def run(estimator, sampler, spp, seed):
        settings = RenderSettings(args.size, args.size, make_sampler(sampler, spp), estimator,
                                  seed)  # fmt: skip
        return render(runtime, source, settings)

    reference = run("mc", "stratified", args.reference_spp, 99).film.image().astype(np.float64)
    rows = []
    for estimator, sampler in PAIRS:
        results = [run(estimator, sampler, args.spp, seed) for seed in args.seeds]
        mses = [float(np.mean((r.film.image() - reference) ** 2)) for r in results]
        host = statistics.mean(r.stats.host_seconds for r in results)
        rows.append({"estimator": estimator, "sampler": sampler, "mse": statistics.mean(mses),
                     "mse_per_seed": mses, "host_s": host})  # fmt: skip
        print(f"{estimator:8s} {sampler:10s} MSE {rows[-1]['mse']:.5f} "
              f"({', '.join(f'{m:.5f}' for m in mses)})  host {host:.2f} s", flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({"settings": {k: str(v) for k, v in vars(args).items()},
                                       "rows": rows}, indent=2))  # fmt: skip
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
