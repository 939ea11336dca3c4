"""Analytic study of the pixel estimators: the paper's Table 2, Figure 2 and Figure 3.

    python bench/analytic_study.py [--quick] [--out DIR] [--runs R] [--sweep-runs R2]
        [--n 4096] [--sweep-n 32 64 ...]

Integrates the six functions of the paper's Table 1 over W = [-1/2, 1/2]^2 (exact integrals
from NOTES.md) with every per-pixel estimator of clrender.estimators, from SPPP sample sets drawn
by the NumPy reference generator; rejected pixels are redrawn by
clrender.estimators.estimate_with_redraw.
All six functions are value columns of the same draws, so each tessellation serves all six.

Outputs (default bench/results/analytic/): results.json (every number), report.md (tables and
the figures with their captions), table2.png, fig2_<function>.png (mean +- std and std against
n), fig3_<function>.png (RMSE against time per estimate). Times ("ms") are wall-clock
milliseconds (time.perf_counter) per estimate, in this process on one core whatever the
executor, excluding sample drawing and function evaluation (the estimator alone: tessellation +
weighted sums); results.json names the clock ("timing") and records the machine's load before
and after ("machine_before", "machine_after"). Error bars on std and RMSE: 95 % percentile
bootstrap intervals over the runs (bench/bootstrap.py). The paper's Table 2 is at n = 4096 over
10 000 runs; a run at another n (--quick: 256) says so beside the paper's columns.
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
from bootstrap import statistic_interval  # noqa: E402
from common import add_executor_options, executor_from_args, machine  # noqa: E402
from figures import (  # noqa: E402
    caption,
    draw_caption,
    legend_beside,
    report_caption,
    save_figure,
)

from clrender.cluster import LocalExecutor  # noqa: E402
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
PAPER_TABLE2_N = 4096
PAPER_TABLE2_RUNS = 10_000
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


def estimate_batch(batch: tuple[int, int, int, tuple[int, ...]]) -> tuple[dict, dict]:
    """The estimates of runs [start, start + count) at intensity n: (count, 6) per estimator,
    and the redraw statistics. Their random numbers come from the stream (stream..., n, start)
    alone, so a run's estimates do not depend on which task or worker computes it."""
    n, start, count, stream = batch
    rng = np.random.default_rng([*stream, n, start])

    def draw(pixel_ids, eps):
        samples = draw_sppp(rng, n, len(pixel_ids), eps=eps)
        return samples, evaluate_all(samples.traced)

    outcome = estimate_with_redraw(ESTIMATOR_NAMES, draw, count, n)
    stats = {key: getattr(outcome.stats, key) for key in REDRAW_STATS}
    return {name: outcome.estimates[name] for name in ESTIMATOR_NAMES}, stats


REDRAW_STATS = ("redraws", "eps_enlargements", "empty_filtered", "recomputed_pixels")


def run_estimates(
    n: int,
    runs: int,
    stream: tuple[int, ...],
    executor=None,
    max_points_per_batch: int = 400_000,
) -> tuple[dict[str, np.ndarray], dict]:
    """(runs, 6) estimates per estimator at intensity n, runs independent pixels, in batches
    of a fixed size (one task each on the executor: bench/common.py's --workers/--scheduler;
    in this process by default): the same numbers whatever runs them."""
    per_batch = max(1, max_points_per_batch // (4 * n))
    batches = [
        (n, start, min(per_batch, runs - start), tuple(stream))
        for start in range(0, runs, per_batch)
    ]
    results: list = [None] * len(batches)
    for index, result in (executor or LocalExecutor()).map(estimate_batch, batches):
        results[index] = result
    estimates = {
        name: np.concatenate([part[name] for part, _ in results]) for name in ESTIMATOR_NAMES
    }
    stats = {key: sum(part_stats[key] for _, part_stats in results) for key in REDRAW_STATS}
    return estimates, stats


TIMING_REPEATS = 3  # calls per estimator and n; the median is kept


def time_estimators(n: int, pixels: int, rng: np.random.Generator) -> dict:
    """Median wall-clock ms (time.perf_counter) per estimate of each estimator alone over
    TIMING_REPEATS calls on `pixels` pixels (holder_1 values, SPPP draws), in this process."""
    samples = draw_sppp(rng, n, pixels)
    values = np.abs(samples.traced[:, 0] * samples.traced[:, 1])
    times = {}
    for name in ESTIMATOR_NAMES:
        runs = []
        for _ in range(TIMING_REPEATS):
            start = time.perf_counter()
            estimate(name, samples, values)
            runs.append(time.perf_counter() - start)
        times[name] = 1e3 * float(np.median(runs)) / pixels
    return times


BOOTSTRAP = 1000  # resamples of the runs behind each error bar


def std_of(runs: np.ndarray, axis: int = 0) -> np.ndarray:
    return np.std(runs, axis=axis, ddof=1)


def rms_of(errors: np.ndarray, axis: int = 0) -> np.ndarray:
    return np.sqrt(np.mean(errors**2, axis=axis))


def summarise(estimates: np.ndarray, exact: np.ndarray, rng: np.random.Generator) -> dict:
    """Per function: mean, std, bias, standard error, RMSE, IQR (NaN-free columns), and the
    95 % bootstrap intervals over the runs of the std and the RMSE (std_ci, rmse_ci: (low,
    high) per function)."""
    runs = len(estimates)
    mean = estimates.mean(axis=0)
    std = std_of(estimates)
    q75, q25 = np.percentile(estimates, [75, 25], axis=0)
    errors = estimates - exact
    return {
        "mean": mean,
        "std": std,
        "std_ci": np.stack(statistic_interval(estimates, std_of, rng, resamples=BOOTSTRAP), -1),
        "bias": mean - exact,
        "se": std / math.sqrt(runs),
        "rmse": rms_of(errors),
        "rmse_ci": np.stack(statistic_interval(errors, rms_of, rng, resamples=BOOTSTRAP), -1),
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
    return {key: np.asarray(value, dtype=float).tolist() for key, value in summary.items()}


# ---------------------------------------------------------------------------------------------
# Reports


def paper_columns_note(runs: int, n: int) -> str:
    """What the paper's columns are, and whether this run's n and runs match them."""
    paper = f"n = {PAPER_TABLE2_N}, {PAPER_TABLE2_RUNS} runs"
    if n == PAPER_TABLE2_N:
        return f"The paper's columns are at the same n ({paper})."
    return (
        f"**This run is at n = {n} ({runs} runs); the paper's columns are at {paper}**: "
        f"they are quoted for reference and are not comparable value for value (std falls "
        f"with n, by about (n / {PAPER_TABLE2_N})^(1/2) for mc and faster for the Voronoi "
        "estimators)."
    )


def table2_markdown(table: dict, runs: int, n: int) -> str:
    paper = f"n = {PAPER_TABLE2_N}"
    lines = [
        f"## Table 2: std over {runs} runs at n = {n} (95 % bootstrap interval; bias +- "
        "standard error; wall-clock ms per estimate, this machine, one core)",
        "",
        paper_columns_note(runs, n),
        "",
        f"| function | estimator | std at n = {n} [95 %] | bias +- se | IQR | wall ms | "
        f"paper std ({paper}) | paper ms ({paper}) |",
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
                f"| {function} | {estimator} | {row['std']:.3g} "
                f"[{row['std_ci'][0]:.3g}, {row['std_ci'][1]:.3g}] | "
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


def figure_caption(figure: str, config: dict, function: str | None = None) -> str:
    """Every parameter of one of the study's figures ("table2", "fig2" or "fig3")."""
    what = {
        "table2": f"Table 2 as bars: std of each per-pixel estimator at n = {config['table_n']}",
        "fig2": f"Figure 2, {function}: mean +- std (left) and std (right) against n",
        "fig3": f"Figure 3, {function}: RMSE against time per estimate",
    }[figure]
    runs = (
        f"{config['runs']} at n = {config['table_n']}"
        if figure == "table2"
        else f"{config['sweep_runs']} per n, n = {', '.join(str(n) for n in config['sweep_n'])}"
    )
    return caption(
        what,
        {
            "function": None
            if function is None
            else f"{function} over W = [-1/2, 1/2]^2, exact integral "
            f"{config['exact'][function]:.6g}",
            "functions": "the six of the paper's Table 1 over W" if function is None else None,
            "runs (independent pixels)": runs,
            "sampler": "SPPP draws of the NumPy reference generator, rejected pixels redrawn",
            "estimators": ", ".join(ESTIMATOR_NAMES),
            "error bars": f"95 % percentile bootstrap interval over the runs ({BOOTSTRAP} "
            "resamples)"
            if figure != "fig2"
            else f"std: 95 % percentile bootstrap interval over the runs ({BOOTSTRAP} "
            "resamples); mean: band of +- 1 std",
            "times": f"wall clock, median of {TIMING_REPEATS} calls on {config['timing_pixels']} "
            "pixels, estimator only"
            if figure == "fig3"
            else None,
            "seed": config["seed"],
            "device": "host, one core (NumPy and Qhull)",
            "paper": f"Table 2 at n = {PAPER_TABLE2_N}, {PAPER_TABLE2_RUNS} runs (not drawn)"
            if figure == "table2"
            else None,
        },
    )


def interval_bars(values, intervals) -> np.ndarray:
    """(2, k) distances below and above each value of its interval, for errorbar's yerr."""
    values, intervals = np.asarray(values), np.asarray(intervals)
    return np.maximum(np.stack([values - intervals[:, 0], intervals[:, 1] - values]), 0.0)


def save_and_close(fig, path: Path) -> None:
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def plot_sweep(sweep: dict, out: Path, config: dict) -> None:
    ns = sweep["n"]
    for f_index, function in enumerate(FUNCTIONS):
        exact = FUNCTIONS[function][1]
        fig, axes = plt.subplots(1, 2, figsize=(13, 5), layout="constrained")
        ax_mean, ax_std = axes
        for name in ESTIMATOR_NAMES:
            mean = np.array([s[name]["mean"][f_index] for s in sweep["summaries"]])
            std = np.array([s[name]["std"][f_index] for s in sweep["summaries"]])
            ci = [s[name]["std_ci"][f_index] for s in sweep["summaries"]]
            (line,) = ax_mean.plot(ns, mean, label=name)
            ax_mean.fill_between(ns, mean - std, mean + std, color=line.get_color(), alpha=0.15)
            ax_std.errorbar(
                ns, std, yerr=interval_bars(std, ci), marker="o", ms=3, capsize=2, label=name
            )
        ax_mean.axhline(exact, color="k", lw=0.8, ls="--", label="exact")
        ax_mean.set_xscale("log", base=2)
        ax_std.set_xscale("log", base=2)
        ax_std.set_yscale("log")
        ax_mean.set(xlabel="n (samples per pixel)", ylabel="estimate", title="mean +- std")
        ax_std.set(xlabel="n", ylabel="std", title="std against n")
        legend_beside(fig, axes)
        draw_caption(fig, figure_caption("fig2", config, function), width=160)
        save_and_close(fig, out / f"fig2_{function}.png")


def plot_efficiency(sweep: dict, out: Path, config: dict) -> None:
    for f_index, function in enumerate(FUNCTIONS):
        fig, ax = plt.subplots(figsize=(8, 5.5), layout="constrained")
        for name in ESTIMATOR_NAMES:
            rmse = [s[name]["rmse"][f_index] for s in sweep["summaries"]]
            ci = [s[name]["rmse_ci"][f_index] for s in sweep["summaries"]]
            ms = [t[name] for t in sweep["ms"]]
            ax.errorbar(
                ms, rmse, yerr=interval_bars(rmse, ci), marker="o", ms=3, capsize=2, label=name
            )
        ax.set(
            xscale="log",
            yscale="log",
            xlabel="wall ms per estimate (estimator only, one core)",
            ylabel="RMSE",
            title="error against time",
        )
        legend_beside(fig, [ax])
        draw_caption(fig, figure_caption("fig3", config, function), width=100)
        save_and_close(fig, out / f"fig3_{function}.png")


def plot_table2(table: dict, out: Path, config: dict) -> None:
    fig, ax = plt.subplots(figsize=(11, 5), layout="constrained")
    width = 0.8 / len(ESTIMATOR_NAMES)
    functions = list(table)
    for i, name in enumerate(ESTIMATOR_NAMES):
        std = [table[f][name]["std"] for f in functions]
        ax.bar(
            np.arange(len(functions)) + i * width,
            std,
            width,
            yerr=interval_bars(std, [table[f][name]["std_ci"] for f in functions]),
            capsize=1.5,
            label=name,
        )
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(functions)) + 0.4, functions, fontsize=8)
    ax.set(ylabel=f"std at n = {config['table_n']}", title="Table 2: std per estimator")
    legend_beside(fig, [ax])
    draw_caption(fig, figure_caption("table2", config), width=140)
    save_and_close(fig, out / "table2.png")


def figures_markdown(config: dict) -> str:
    """The figures with their captions, for the report."""
    lines = [
        "## Figures",
        "",
        "![table2](table2.png)",
        "",
        report_caption(figure_caption("table2", config)),
        "",
    ]
    for function in FUNCTIONS:
        for figure in ("fig2", "fig3"):
            lines += [
                f"![{figure} {function}]({figure}_{function}.png)",
                "",
                report_caption(figure_caption(figure, config, function)),
                "",
            ]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# Main


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smoke run of a few seconds")
    parser.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).parent / "results" / "analytic",
        help="output folder (default bench/results/analytic)",
    )
    parser.add_argument("--runs", type=int, default=None, help="Table 2 runs (default 10000)")
    parser.add_argument(
        "--sweep-runs", type=int, default=None, help="runs per n for Figure 2 (default 1000)"
    )
    parser.add_argument("--n", type=int, default=None, help="Table 2 intensity (default 4096)")
    parser.add_argument(
        "--sweep-n",
        type=int,
        nargs="+",
        default=None,
        help="intensities of Figures 2 and 3 (default 32 64 ... 16384; --quick: 32 ... 256)",
    )
    parser.add_argument(
        "--seed", type=int, default=2025, help="seed of the draws and the bootstrap (default 2025)"
    )
    add_executor_options(parser)
    return parser.parse_args(argv)


def main(argv=None) -> None:
    args = parse_args(argv)
    quick = args.quick
    table_n = args.n or (256 if quick else 4096)
    runs = args.runs or (100 if quick else 10_000)
    sweep_runs = args.sweep_runs or (40 if quick else 1000)
    sweep_ns = args.sweep_n or [2**k for k in range(5, 9 if quick else 15)]
    timing_pixels = 5 if quick else 20
    slope_n_min = 64 if quick else 256
    rng = np.random.default_rng(args.seed)
    # The error bars' resampling has its own stream: the draws do not depend on it
    boot_rng = np.random.default_rng([args.seed, 1])
    exact = np.array([e for _, e in FUNCTIONS.values()])
    args.out.mkdir(parents=True, exist_ok=True)
    machine_before = machine()

    with executor_from_args(args) as executor:
        # Table 2 (its runs from stream (seed, 2), the sweep's from (seed, 3))
        start = time.perf_counter()
        estimates, redraw_stats = run_estimates(table_n, runs, (args.seed, 2), executor)
        table_ms = time_estimators(table_n, timing_pixels, rng)
        table = {}
        for f_index, function in enumerate(FUNCTIONS):
            table[function] = {}
            for name in ESTIMATOR_NAMES:
                s = summarise(estimates[name], exact, boot_rng)
                table[function][name] = {
                    key: np.asarray(v)[f_index].tolist() for key, v in s.items()
                }
                table[function][name]["ms"] = table_ms[name]
        print(table2_markdown(table, runs, table_n))
        took = time.perf_counter() - start
        print(f"redraw statistics: {redraw_stats}; Table 2 took {took:.0f} s")

        # Figure 2 and 3 sweep
        sweep = {"n": sweep_ns, "summaries": [], "ms": [], "redraw_stats": []}
        for n in sweep_ns:
            estimates_n, stats_n = run_estimates(n, sweep_runs, (args.seed, 3), executor)
            sweep["summaries"].append(
                {
                    name: to_lists(summarise(estimates_n[name], exact, boot_rng))
                    for name in ESTIMATOR_NAMES
                }
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
    plot_table2(table, args.out, config)
    plot_sweep(sweep, args.out, config)
    plot_efficiency(sweep, args.out, config)
    results = {
        "config": config,
        "table2": table,
        "table2_redraw_stats": redraw_stats,
        "paper_table2": PAPER_TABLE2,
        "sweep": sweep,
        "slopes": slopes,
        "slope_explanation": SLOPE_EXPLANATION,
        "timing": {
            "clock": "wall",
            "timer": "time.perf_counter",
            "ms": "milliseconds per estimate of the estimator alone (tessellation and weighted "
            "sums; no drawing or function evaluation): the median of "
            f"{TIMING_REPEATS} calls on {timing_pixels} pixels, divided by the pixels",
            "where": "this process, one thread, whatever --workers / --scheduler",
        },
        # The machine is shared: its load before and after the study
        "machine_before": machine_before,
        "machine_after": machine(),
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
        "",
        figures_markdown(config),
    ]
    (args.out / "report.md").write_text("\n".join(report) + "\n")
    print(f"wrote {args.out}/results.json, report.md and PNG charts")


if __name__ == "__main__":
    main()
