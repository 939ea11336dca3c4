"""The bias of the unnormalised Voronoi estimator (`vor`, the paper's E_V) over SPPP sample sets,
beside mc and ivor, on analytic images whose exact pixel integrals are known.

    python bench/vor_bias.py [--n 1 4 16 64] [--kinds smooth bowl] [--seeds 48] [--size 64]
        [--out DIR]

Over a Poisson process on the whole plane, E_V is unbiased (Mecke's formula: a point added to
the process has a cell of mean area 1/n). The paper's construction keeps the process's points
in W, plus a fixed floor(n (4 eps + 4 eps^2)) auxiliary nuclei in the strip W' \\ W and none
beyond, and rejects a pixel with an unbounded cell: cells near the strip are larger than over
the plane, so E_V comes out slightly high, most at small n. mc (sum f / n) and ivor (one
tessellation of the whole image's nuclei) are exactly unbiased and serve as controls.

For each image kind and n, `--seeds` renders (seeds 0, 1, ...) of a size x size analytic image;
each render gives the ratio of its image mean to the exact mean; the table prints the mean
ratio over the seeds minus 1 with its standard error, and how many standard errors from 0 it
is. Output: DIR/results.json (default bench/results/vor_bias/) and the table on stdout.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, command_line, machine, markdown_table, write_json  # noqa: E402

import clrender  # noqa: E402
from clrender.analytic import analytic_image  # noqa: E402

ESTIMATORS = ("mc", "vor", "ivor")


def relative_bias(kind: str, n: int, seeds: int, size: int) -> dict:
    """{estimator: (mean - exact) / exact over the seeds, its standard error, the z score},
    and the renders' redraws."""
    exact = analytic_image(f"analytic:{kind}", size, size).pixel_integrals(size, size)
    exact_mean = float(exact[..., 0].mean())
    ratios = {name: [] for name in ESTIMATORS}
    redraws = 0
    for seed in range(seeds):
        with warnings.catch_warnings():  # the small-n advice, which this study is about
            warnings.simplefilter("ignore")
            result = clrender.render(
                f"analytic:{kind}", spp=n, estimators=list(ESTIMATORS), resolution=size, seed=seed
            )
        redraws += result.stats.redrawn_pixels
        for name in ESTIMATORS:
            ratios[name].append(float(result.images[name][..., 0].astype(np.float64).mean()))
    row = {"redrawn_pixels": redraws}
    for name, means in ratios.items():
        values = np.asarray(means) / exact_mean - 1.0
        error = float(values.std(ddof=1) / np.sqrt(len(values)))
        bias = float(values.mean())
        row[name] = {"bias": bias, "standard_error": error, "z": bias / error if error else 0.0}
    return row


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[1, 4, 16, 64])
    parser.add_argument("--kinds", nargs="+", default=["smooth", "bowl"])
    parser.add_argument("--seeds", type=int, default=48)
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--out", type=Path, default=RESULTS / "vor_bias")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    results = {}
    rows = []
    for kind in args.kinds:
        for n in args.n:
            row = relative_bias(kind, n, args.seeds, args.size)
            results[f"{kind} n={n}"] = row
            rows.append(
                [kind, n]
                + [
                    f"{row[name]['bias']:+.2%} ± {row[name]['standard_error']:.2%} "
                    f"({row[name]['z']:+.1f})"
                    for name in ESTIMATORS
                ]
                + [row["redrawn_pixels"]]
            )
            print(f"{kind} n={n} done", file=sys.stderr, flush=True)
    table = markdown_table(
        ["image", "n"] + [f"{name}: bias ± s.e. (z)" for name in ESTIMATORS] + ["redraws"], rows
    )
    print(table)
    write_json(
        args.out / "results.json",
        {
            "command": command_line("vor_bias.py", argv),
            "seeds": args.seeds,
            "size": args.size,
            "machine": machine(),
            "seconds": time.perf_counter() - start,
            "results": results,
        },
    )


if __name__ == "__main__":
    main()
