"""The bias of the unnormalised Voronoi estimator (`vor`, the paper's E_V) over SPPP sample sets,
beside mc and ivor, on analytic images whose exact pixel integrals are known.

    python bench/vor_bias.py [--n 1 2 4 16 64] [--kinds smooth bowl] [--seeds 200] [--size 64]
        [--simulate TRIALS] [--out DIR]

Over a Poisson process on the whole plane, E_V is unbiased (Mecke's formula: a point added to
the process has a cell of mean area 1/n). The paper's construction keeps the process's points in
W, plus a fixed floor(n (4 eps + 4 eps^2)) auxiliary nuclei in the strip W' \\ W and none
beyond, and rejects a pixel with an unbounded cell: cells near the strip are larger than over
the plane, so E_V is biased, most at small n, in either direction (README). mc (sum f / n) and
ivor (one tessellation of the whole image's nuclei) are exactly unbiased and serve as controls.

For each image kind and n, `--seeds` renders (seeds 0, 1, ...) of a size x size analytic image;
each render gives the ratio of its image mean to the exact mean; the table prints the mean ratio
over the seeds minus 1 with its standard error, and how many standard errors from 0 it is.
--simulate TRIALS also simulates the construction apart from clrender's samplers and cells
(simulated_bias: f = 1, SciPy's Voronoi), TRIALS pixels per n. Output: DIR/results.json (default
bench/results/vor_bias/) and the table on stdout.
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


def simulated_bias(n: int, trials: int, seed: int = 1) -> tuple[float, float]:
    """E_V - 1 of f = 1 (the sum of the W nuclei's cell areas) and its standard error, over
    `trials` pixels of the paper's construction simulated apart from clrender's samplers and
    cells: N ~ Poisson(n) uniform in W, floor(n (4 eps + 4 eps^2)) uniform by area in the strip
    (rejection from W'), cells by scipy.spatial.Voronoi, a pixel with an unbounded W cell drawn
    again. Only eps comes from clrender (clrender.sppp.sppp_eps, checked against the paper)."""
    from scipy.spatial import QhullError, Voronoi

    from clrender.sppp import sppp_eps

    rng = np.random.default_rng(seed)
    eps = sppp_eps(n)
    n_aux = int(np.floor(n * (4 * eps + 4 * eps * eps)))
    half = 0.5 + eps
    sums = []
    while len(sums) < trials:
        count = rng.poisson(n)
        if count == 0:
            sums.append(0.0)
            continue
        strip = np.empty((0, 2))
        while len(strip) < n_aux:
            points = rng.uniform(-half, half, (2 * n_aux, 2))
            strip = np.vstack([strip, points[np.abs(points).max(axis=1) > 0.5]])
        nuclei = np.vstack([rng.uniform(-0.5, 0.5, (count, 2)), strip[:n_aux]])
        try:
            cells = Voronoi(nuclei)
        except QhullError:
            continue
        areas = []
        for index in range(count):
            region = cells.regions[cells.point_region[index]]
            if -1 in region or not region:
                break  # unbounded: the pixel is drawn again
            corners = cells.vertices[region]
            centre = corners.mean(axis=0)
            order = np.argsort(np.arctan2(*(corners - centre).T[::-1]))
            x, y = corners[order].T
            areas.append(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
        else:
            sums.append(sum(areas))
    values = np.asarray(sums) - 1.0
    return float(values.mean()), float(values.std(ddof=1) / np.sqrt(len(values)))


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
    parser.add_argument("--n", type=int, nargs="+", default=[1, 2, 4, 16, 64])
    parser.add_argument("--kinds", nargs="+", default=["smooth", "bowl"])
    parser.add_argument("--seeds", type=int, default=200)
    parser.add_argument(
        "--simulate",
        type=int,
        default=0,
        metavar="TRIALS",
        help="also simulate the construction apart from clrender (f = 1), TRIALS pixels per n",
    )
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
    simulated = {}
    for n in args.n if args.simulate else []:
        bias, error = simulated_bias(n, args.simulate)
        simulated[str(n)] = {"bias": bias, "standard_error": error, "trials": args.simulate}
        print(f"simulated, f = 1, n = {n}: E_V - 1 = {bias:+.2%} ± {error:.2%}")
    write_json(
        args.out / "results.json",
        {
            "command": command_line("vor_bias.py", argv),
            "seeds": args.seeds,
            "size": args.size,
            "machine": machine(),
            "seconds": time.perf_counter() - start,
            "results": results,
            "simulated": simulated,
        },
    )


if __name__ == "__main__":
    main()
