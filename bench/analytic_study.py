"""Analytic study of the pixel estimators: the paper's Table 2, Figure 2 and Figure 3.

    python bench/analytic_study.py [--quick] [--out DIR] [--runs R] [--sweep-runs R2]

Integrates the six functions of the paper's Table 1 over W = [-1/2, 1/2]^2 (exact integrals
from NOTES.md) with every per-pixel estimator of clrender.estimators, from SPPP sample sets drawn
by the NumPy reference generator; rejected pixels are redrawn by
clrender.estimators.estimate_with_redraw.
All six functions are value columns of the same draws, so each tessellation serves all six.

Outputs (default bench/results/analytic/): results.json (every number), report.md (tables),
table2.png, fig2_<function>.png (mean +- std and std against n), fig3_<function>.png (RMSE
against time per estimate). Times are per estimate, one core, excluding sample drawing and
function evaluation (the estimator alone: tessellation + weighted sums).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from clrender.estimators import ESTIMATORS, estimate, estimate_with_redraw  # noqa: E402
from clrender.sppp import draw_sppp  # noqa: E402

# The per-pixel estimators (the image-level ones tessellate whole images, not lone pixels).
ESTIMATOR_NAMES = [name for name, entry in ESTIMATORS.items() if not entry.image_level]


def _holder(a):
    return lambda x, y: np.abs(x * y) ** a


def _not_holder(x, y):
    with np.errstate(divide="ignore", invalid="ignore"):
        value = x * y * np.sin(1.0 / x) * np.sin(1.0 / y)
    return np.where((x == 0) | (y == 0), 0.0, value)  # the continuous extension


def _discontinuity(x, y):
    with np.errstate(divide="ignore"):
        return 1.0 / np.hypot(x, y)


# name -> (f, exact integral over W); NOTES.md section 2.
FUNCTIONS = {
    "holder_1": (_holder(1.0), 1.0 / 16.0),
    "holder_0.5": (_holder(0.5), 2.0 / 9.0),
    "holder_0.1": (_holder(0.1), (0.5**0.1 / 1.1) ** 2),
    "holder_0.01": (_holder(0.01), (0.5**0.01 / 1.01) ** 2),
    "not_holder": (_not_holder, 0.0029017171),
    "discontinuity": (_discontinuity, 4.0 * math.log(1.0 + math.sqrt(2.0))),
}
HOLDER_EXPONENT = {"holder_1": 1.0, "holder_0.5": 0.5, "holder_0.1": 0.1, "holder_0.01": 0.01}

# The paper's Table 2 (std over 10 000 runs at n = 4096; ms per estimate on their machine).
PAPER_TABLE2 = {
    "holder_1": (0.00086, 0.000171, 0.000167, 2.28, 201.97, 149.87),
    "holder_0.5": (0.001786, 0.000291, 0.000292, 4.04, 204.82, 150.30),
    "holder_0.1": (0.001461, 0.000299, 0.000297, 3.78, 216.57, 156.93),
    "holder_0.01": (0.000244, 1e-6, 1e-6, 4.07, 229.09, 151.75),
    "not_holder": (0.000585, 0.000179, 0.000178, 5.45, 228.61, 159.33),
    "discontinuity": (0.10716, 0.079052, 0.10411, 2.53, 231.97, 152.40),
}

SLOPE_EXPLANATION = """\
Std slopes (log std against log n). Proposition 1 bounds Var[E_V] by n^(-1-2a/d), i.e. a std
slope of -(1/2 + a/2) for holder_a (d = 2), against -1/2 for mc. Differences:
- E_V (vor) sums f(x) v(x) with f *restricted to W*, which jumps from f(edge) to 0 at the pixel
  edge: cells of W nuclei overhang into the strip and strip cells cover part of W. That is the
  indicator case of the paper, Var ~ n^(-1-1/d): std slope -3/4 at best, whatever the Hoelder
  exponent inside W (holder_1 would otherwise give -1).
- The self-normalised form (vor_sn, fvor) divides by sum v, which cancels the leading part of
  that edge error (for constant f it is exact), so it decays faster than vor, but it is a ratio
  estimator with an O(1/n) bias.
- pvor sees no edge when the periodic extension of f is continuous (true for |xy|^a, which is
  even in x and y), so it follows the Hoelder rate; cvor is biased (its RMSE levels off).
- holder_a for small a is Hoelder only near the axes through the centre; elsewhere it is
  smooth, so measured slopes are steeper than the worst-case bound -(1/2 + a/2).
- discontinuity has infinite variance under mc: std estimates are dominated by rare samples
  near the centre and their slopes are not meaningful; compare the IQR instead.
"""


def evaluate_all(positions: np.ndarray) -> np.ndarray:
    """(T, 6) values: every function of FUNCTIONS at every position."""
    x, y = positions[:, 0], positions[:, 1]
    return np.column_stack([f(x, y) for f, _ in FUNCTIONS.values()])


def run_estimates(
    n: int, runs: int, rng: np.random.Generator, max_points_per_batch: int = 400_000
) -> tuple[dict[str, np.ndarray], dict]:
    """(runs, 6) estimates per estimator at intensity n, runs independent pixels."""

    def draw(pixel_ids, eps):
        samples = draw_sppp(rng, n, len(pixel_ids), eps=eps)
        return samples, evaluate_all(samples.traced)

    per_batch = max(1, max_points_per_batch // (4 * n))
    parts: dict[str, list[np.ndarray]] = {name: [] for name in ESTIMATOR_NAMES}
    stats = {"redraws": 0, "eps_enlargements": 0, "empty_filtered": 0, "recomputed_pixels": 0}
    for start in range(0, runs, per_batch):
        count = min(per_batch, runs - start)
        outcome = estimate_with_redraw(ESTIMATOR_NAMES, draw, count, n)
        for name in ESTIMATOR_NAMES:
            parts[name].append(outcome.estimates[name])
        for key in stats:
            stats[key] += getattr(outcome.stats, key)
    return {name: np.concatenate(p) for name, p in parts.items()}, stats


def time_estimators(n: int, pixels: int, rng: np.random.Generator, repeats: int = 3) -> dict:
    """Median ms per estimate of each estimator alone (holder_1 values, SPPP draws)."""
    samples = draw_sppp(rng, n, pixels)
    values = np.abs(samples.traced[:, 0] * samples.traced[:, 1])
    times = {}
    for name in ESTIMATOR_NAMES:
        runs = []
        for _ in range(repeats):
            start = time.perf_counter()
            estimate(name, samples, values)
            runs.append(time.perf_counter() - start)
        times[name] = 1e3 * float(np.median(runs)) / pixels
    return times


def summarise(estimates: np.ndarray, exact: np.ndarray) -> dict:
    """Per function: mean, std, bias, standard error, RMSE, IQR (NaN-free columns)."""
    runs = len(estimates)
    mean = estimates.mean(axis=0)
    std = estimates.std(axis=0, ddof=1)
    q75, q25 = np.percentile(estimates, [75, 25], axis=0)
    return {
        "mean": mean,
        "std": std,
        "bias": mean - exact,
        "se": std / math.sqrt(runs),
        "rmse": np.sqrt(((estimates - exact) ** 2).mean(axis=0)),
        "iqr": q75 - q25,
    }


def fit_slope(ns: list[int], stds: list[float], n_min: int) -> float:
    keep = [(n, s) for n, s in zip(ns, stds, strict=True) if n >= n_min and s > 0]
    if len(keep) < 2:
        return float("nan")
    x, y = np.log([k[0] for k in keep]), np.log([k[1] for k in keep])
    return float(np.polyfit(x, y, 1)[0])


def predicted_slope(function: str, estimator: str) -> float | None:
    entry = ESTIMATORS[estimator]
    if entry.cells == "none":  # mc, mc_n
        return -0.5
    a = HOLDER_EXPONENT.get(function)
    if a is None or entry.cells == "clipped":  # cvor: biased
        return None
    return -(0.5 + a / 2.0)


def to_lists(summary: dict) -> dict:
    return {key: [float(v) for v in value] for key, value in summary.items()}


# ---------------------------------------------------------------------------------------------
# Reports


def table2_markdown(table: dict, runs: int, n: int) -> str:
    lines = [
        f"## Table 2: std over {runs} runs at n = {n} (bias +- standard error; "
        "ms per estimate, this machine, one core)",
        "",
        "| function | estimator | std | bias +- se | IQR | ms | paper std | paper ms |",
        "|---|---|---|---|---|---|---|---|",
    ]
    paper_columns = {"mc_n": 0, "vor_sn": 1, "fvor": 2}
    for function, rows in table.items():
        for estimator, row in rows.items():
            paper = PAPER_TABLE2[function]
            column = paper_columns.get(estimator)
            paper_std = (
                ""
                if column is None
                else ("< 1e-6" if paper[column] <= 1e-6 else f"{paper[column]:.3g}")
            )
            paper_ms = f"{paper[column + 3]:.1f}" if column is not None else ""
            lines.append(
                f"| {function} | {estimator} | {row['std']:.3g} | "
                f"{row['bias']:+.2e} +- {row['se']:.1e} | {row['iqr']:.3g} | "
                f"{row['ms']:.2f} | {paper_std} | {paper_ms} |"
            )
    lines += [
        "",
        "Paper columns: the authors' mc draws exactly n points and averages them, so "
        "it sits beside mc_n (our mc divides by the intensity n under Poisson N, whose "
        "count noise dominates for nearly constant f such as holder_0.01); their 'vor' "
        "normalises E_V, so it sits beside vor_sn. Their holder_0.01 stds were below "
        "1e-6 only through half-float storage.",
    ]
    return "\n".join(lines)


def slopes_markdown(slopes: dict, n_min: int) -> str:
    lines = [
        f"## Figure 2 slopes: log-log slope of std against n (n >= {n_min})",
        "",
        "| function | " + " | ".join(ESTIMATOR_NAMES) + " |",
        "|---|" + "---|" * len(ESTIMATOR_NAMES),
    ]
    for function, row in slopes.items():
        cells = []
        for estimator in ESTIMATOR_NAMES:
            measured = row[estimator]["measured"]
            predicted = row[estimator]["predicted"]
            cells.append(f"{measured:.2f}" + (f" ({predicted:.2f})" if predicted else ""))
        lines.append(f"| {function} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "In brackets: Proposition 1's slope -(1/2 + a/2) (mc: -1/2).",
        "",
        SLOPE_EXPLANATION,
    ]
    return "\n".join(lines)


def plot_sweep(sweep: dict, out: Path) -> None:
    ns = sweep["n"]
    for f_index, function in enumerate(FUNCTIONS):
        exact = FUNCTIONS[function][1]
        fig, (ax_mean, ax_std) = plt.subplots(1, 2, figsize=(12, 4.5))
        for name in ESTIMATOR_NAMES:
            mean = np.array([s[name]["mean"][f_index] for s in sweep["summaries"]])
            std = np.array([s[name]["std"][f_index] for s in sweep["summaries"]])
            (line,) = ax_mean.plot(ns, mean, label=name)
            ax_mean.fill_between(ns, mean - std, mean + std, color=line.get_color(), alpha=0.15)
            ax_std.loglog(ns, std, marker="o", ms=3, label=name)
        ax_mean.axhline(exact, color="k", lw=0.8, ls="--", label="exact")
        ax_mean.set_xscale("log", base=2)
        ax_mean.set(
            xlabel="n (samples per pixel)", ylabel="estimate", title=f"{function}: mean +- std"
        )
        ax_std.set(xlabel="n", ylabel="std", title=f"{function}: std against n")
        ax_mean.legend(fontsize=7)
        ax_std.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / f"fig2_{function}.png", dpi=110)
        plt.close(fig)


def plot_efficiency(sweep: dict, out: Path) -> None:
    for f_index, function in enumerate(FUNCTIONS):
        fig, ax = plt.subplots(figsize=(6, 4.5))
        for name in ESTIMATOR_NAMES:
            rmse = [s[name]["rmse"][f_index] for s in sweep["summaries"]]
            ms = [t[name] for t in sweep["ms"]]
            ax.loglog(ms, rmse, marker="o", ms=3, label=name)
        ax.set(
            xlabel="ms per estimate (estimator only, one core)",
            ylabel="RMSE",
            title=f"{function}: error against time",
        )
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / f"fig3_{function}.png", dpi=110)
        plt.close(fig)


def plot_table2(table: dict, out: Path) -> None:
    fig, ax = plt.subplots(figsize=(10, 4.5))
    width = 0.8 / len(ESTIMATOR_NAMES)
    functions = list(table)
    for i, name in enumerate(ESTIMATOR_NAMES):
        ax.bar(
            np.arange(len(functions)) + i * width,
            [table[f][name]["std"] for f in functions],
            width,
            label=name,
        )
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(functions)) + 0.4, functions, fontsize=8)
    ax.set(ylabel="std", title="Table 2: std per estimator")
    ax.legend(fontsize=7, ncol=4)
    fig.tight_layout()
    fig.savefig(out / "table2.png", dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------------------------
# Main


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smoke run of a few seconds")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "analytic")
    parser.add_argument("--runs", type=int, default=None, help="Table 2 runs (default 10000)")
    parser.add_argument(
        "--sweep-runs", type=int, default=None, help="runs per n for Figure 2 (default 1000)"
    )
    parser.add_argument("--n", type=int, default=None, help="Table 2 intensity (default 4096)")
    parser.add_argument("--seed", type=int, default=2025)
    return parser.parse_args(argv)


def main(argv=None) -> None:
    args = parse_args(argv)
    quick = args.quick
    table_n = args.n or (256 if quick else 4096)
    runs = args.runs or (100 if quick else 10_000)
    sweep_runs = args.sweep_runs or (40 if quick else 1000)
    sweep_ns = [2**k for k in range(5, 9 if quick else 15)]
    timing_pixels = 5 if quick else 20
    slope_n_min = 64 if quick else 256
    rng = np.random.default_rng(args.seed)
    exact = np.array([e for _, e in FUNCTIONS.values()])
    args.out.mkdir(parents=True, exist_ok=True)

    # Table 2
    start = time.perf_counter()
    estimates, redraw_stats = run_estimates(table_n, runs, rng)
    table_ms = time_estimators(table_n, timing_pixels, rng)
    table = {}
    for f_index, function in enumerate(FUNCTIONS):
        table[function] = {}
        for name in ESTIMATOR_NAMES:
            s = summarise(estimates[name], exact)
            table[function][name] = {key: float(v[f_index]) for key, v in s.items()}
            table[function][name]["ms"] = table_ms[name]
    print(table2_markdown(table, runs, table_n))
    print(f"redraw statistics: {redraw_stats}; Table 2 took {time.perf_counter() - start:.0f} s")

    # Figure 2 and 3 sweep
    sweep = {"n": sweep_ns, "summaries": [], "ms": [], "redraw_stats": []}
    for n in sweep_ns:
        estimates_n, stats_n = run_estimates(n, sweep_runs, rng)
        sweep["summaries"].append(
            {name: to_lists(summarise(estimates_n[name], exact)) for name in ESTIMATOR_NAMES}
        )
        sweep["ms"].append(time_estimators(n, timing_pixels, rng))
        sweep["redraw_stats"].append(stats_n)
        print(f"sweep n = {n}: done ({stats_n})", flush=True)
    slopes = {}
    for f_index, function in enumerate(FUNCTIONS):
        slopes[function] = {}
        for name in ESTIMATOR_NAMES:
            stds = [s[name]["std"][f_index] for s in sweep["summaries"]]
            slopes[function][name] = {
                "measured": fit_slope(sweep_ns, stds, slope_n_min),
                "predicted": predicted_slope(function, name),
            }
    print(slopes_markdown(slopes, slope_n_min))

    plot_table2(table, args.out)
    plot_sweep(sweep, args.out)
    plot_efficiency(sweep, args.out)
    config = {
        "table_n": table_n,
        "runs": runs,
        "sweep_runs": sweep_runs,
        "sweep_n": sweep_ns,
        "seed": args.seed,
        "quick": quick,
        "slope_n_min": slope_n_min,
        "timing_pixels": timing_pixels,
        "exact": dict(zip(FUNCTIONS, exact.tolist(), strict=True)),
    }
    results = {
        "config": config,
        "table2": table,
        "table2_redraw_stats": redraw_stats,
        "paper_table2": PAPER_TABLE2,
        "sweep": sweep,
        "slopes": slopes,
        "slope_explanation": SLOPE_EXPLANATION,
    }
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    report = [
        "# Analytic study of the pixel estimators",
        "",
        f"Command: python bench/analytic_study.py {' '.join(argv or sys.argv[1:])}",
        "",
        table2_markdown(table, runs, table_n),
        "",
        slopes_markdown(slopes, slope_n_min),
    ]
    (args.out / "report.md").write_text("\n".join(report) + "\n")
    print(f"wrote {args.out}/results.json, report.md and PNG charts")


if __name__ == "__main__":
    main()
