"""Image-level tessellation (ivor, ivor_sn) against per-pixel SPPP estimators on analytic images.

    python bench/image_tessellation_study.py [--quick] [--out DIR] [--runs R] [--size S]
        [--runs-per-task K] [--workers N | --scheduler ADDRESS]

An S x S image with four analytic functions as value columns (clrender.analytic's edge, smooth
and disc laid out for the image, plus a linear ramp), exact pixel integrals. For each n in
64, 256, 1024 and each of R runs:
- image level: one Poisson(n) realisation on the image grown by a frame of ceil(2 eps(n))
  pixels, estimated by clrender.estimators.image.estimate_image (ivor and ivor_sn share it);
- per pixel: independent SPPP sample sets per pixel (NumPy reference generator), estimated by
  mc, vor, vor_sn, fvor, pvor with the paper's redraws (clrender.estimators.estimate_with_redraw).
Per (n, function, estimator): bias = mean error over pixels and runs, with its standard error
from the spread of per-run image means; std = per-pixel std over runs, averaged over pixels
(RMS); rmse likewise. Time: microseconds per pixel estimate, one core, estimator alone
(tessellation + sums; not drawing, not evaluating f), median of the runs; ivor and ivor_sn
report the same time (one tessellation serves both; so do vor, vor_sn and fvor, but each is
timed alone here, as in bench/analytic_study.py).

Runs as tasks: run r at n draws from its own random stream (seed, n, r), so its numbers do not
depend on which task computes it; tasks of --runs-per-task runs (all n in one map) go to the
executor of --workers N (a Dask LocalCluster of N processes) or --scheduler ADDRESS, this process
by default, and every number but the times is bit-identical whatever the executor and the split
(tests/test_cluster_studies.py). The times are measured inside the tasks, where they ran: on a
LocalCluster sharing this machine's cores they include that contention (results.json names the
executor). (Before the executor every run drew from one stream in order, so this version's draws
and numbers differ from that version's; the statistics are the same.)

Outputs (default bench/results/image_tessellation/): results.json, report.md, study.png.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import (  # noqa: E402
    add_executor_options,
    executor_from_args,
    executor_label,
    machine,
    positive_int,
)

from clrender.analytic import analytic_functions  # noqa: E402
from clrender.cluster import LocalExecutor  # noqa: E402
from clrender.estimators import ESTIMATORS, estimate, estimate_with_redraw  # noqa: E402
from clrender.estimators.image import (  # noqa: E402
    draw_plane_poisson,
    estimate_image,
    guard_distance,
)
from clrender.sppp import draw_sppp  # noqa: E402

FUNCTIONS = ("edge", "smooth", "disc", "ramp")
IMAGE_ESTIMATORS = tuple(name for name, entry in ESTIMATORS.items() if entry.image_level)
PIXEL_ESTIMATORS = ("mc", "vor", "vor_sn", "fvor", "pvor")
NS = (64, 256, 1024)


class AnalyticColumns:
    """The four functions of the study on an S x S image, and their exact pixel integrals."""

    def __init__(self, size: int):
        self.size = size
        self.functions = analytic_functions(size, size)
        ys, xs = np.mgrid[0:size, 0:size] + 0.5
        exact = [self.functions[k].pixel_integrals(size, size) for k in FUNCTIONS[:3]]
        self.exact = np.stack(exact + [self.ramp(xs, ys)], axis=-1)  # (S, S, 4)

    def ramp(self, x, y):
        return 0.2 + 0.3 * x / self.size + 0.2 * y / self.size

    def values(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        columns = [self.functions[k].value(x, y) for k in FUNCTIONS[:3]]
        return np.column_stack(columns + [self.ramp(x, y)])


def image_level_run(image: AnalyticColumns, n: int, rng) -> tuple[dict, float, dict]:
    """One realisation: estimates (S, S, 4) per estimator, seconds, statistics."""
    size = image.size
    frame = math.ceil(guard_distance(n))
    points = draw_plane_poisson(rng, n, (-frame, -frame, size + frame, size + frame))
    values = image.values(points[:, 0], points[:, 1])
    start = time.perf_counter()
    result = estimate_image(points, values, size, size, n, frame)
    seconds = time.perf_counter() - start
    return result.estimates, seconds, vars(result.stats)


def pixel_level_run(image: AnalyticColumns, n: int, rng) -> tuple[dict, dict, int]:
    """Independent SPPP pixels: estimates (S, S, 4) per estimator (with redraws), seconds per
    estimator alone on the first draw, and the number of redraws."""
    size = image.size
    pixels = size * size

    def positions(samples, ids):
        owner = np.repeat(np.asarray(ids), samples.counts)
        return (
            owner % size + 0.5 + samples.traced[:, 0],
            owner // size + 0.5 + samples.traced[:, 1],
        )

    def values(samples, ids):
        return image.values(*positions(samples, ids))

    def draw(ids, eps):
        samples = draw_sppp(rng, n, len(ids), eps=eps)
        return samples, values(samples, ids)

    outcome = estimate_with_redraw(PIXEL_ESTIMATORS, draw, pixels, n)
    estimates = {k: v.reshape(size, size, -1) for k, v in outcome.estimates.items()}
    samples = draw_sppp(rng, n, pixels)
    sample_values = values(samples, np.arange(pixels))
    seconds = {}
    for name in PIXEL_ESTIMATORS:
        start = time.perf_counter()
        estimate(name, samples, sample_values)
        seconds[name] = time.perf_counter() - start
    return estimates, seconds, outcome.stats.redraws


def summarise(errors: np.ndarray) -> dict:
    """errors: (runs, S, S, 4). Per function: bias, se, std, rmse (lists of 4 floats)."""
    runs = len(errors)
    image_means = errors.mean(axis=(1, 2))
    se = image_means.std(axis=0, ddof=1) / math.sqrt(runs) if runs > 1 else image_means[0] * 0
    std = np.sqrt(errors.var(axis=0, ddof=1).mean(axis=(0, 1)))
    rmse = np.sqrt((errors**2).mean(axis=(0, 1, 2)))
    return {
        "bias": image_means.mean(axis=0).tolist(),
        "se": se.tolist(),
        "std": std.tolist(),
        "rmse": rmse.tolist(),
    }


@dataclass(frozen=True)
class RunRange:
    """Runs [first, first + count) at intensity n of an S x S image: one task. Run r draws
    from the random stream (seed, n, r) alone."""

    n: int
    first: int
    count: int
    size: int
    seed: int


def run_range(task: RunRange) -> list[tuple[dict, dict, dict]]:
    """Per run: errors (S, S, 4) per estimator, seconds per estimator (measured where the task
    ran), counters."""
    image = AnalyticColumns(task.size)
    out = []
    for run in range(task.first, task.first + task.count):
        rng = np.random.default_rng([task.seed, task.n, run])
        est, seconds, stats = image_level_run(image, task.n, rng)
        errors = {name: est[name] - image.exact for name in IMAGE_ESTIMATORS}
        times = dict.fromkeys(IMAGE_ESTIMATORS, seconds)
        counters = {key: stats[key] for key in ("widened_blocks", "uncertified_nuclei")}
        est, seconds, redraws = pixel_level_run(image, task.n, rng)
        for name in PIXEL_ESTIMATORS:
            errors[name] = est[name] - image.exact
            times[name] = seconds[name]
        out.append((errors, times, {**counters, "redraws": redraws}))
    return out


def study_ns(
    size: int, runs: int, seed: int, executor=None, runs_per_task: int = 1, ns=NS
) -> dict[str, dict]:
    """{str(n): {"estimators": {name: summary}, "counters": {...}}} over the runs of every n,
    from tasks of runs_per_task runs (all n in one map): the same numbers for any split and
    any executor (this process by default)."""
    tasks = [
        RunRange(n, first, min(runs_per_task, runs - first), size, seed)
        for n in ns
        for first in range(0, runs, runs_per_task)
    ]
    done: list = [None] * len(tasks)
    for index, result in (executor or LocalExecutor()).map(run_range, tasks):
        done[index] = result
    by_n = {}
    for n in ns:
        per_run = [
            run for task, part in zip(tasks, done, strict=True) if task.n == n for run in part
        ]
        names = IMAGE_ESTIMATORS + PIXEL_ESTIMATORS
        counters = {"redraws": 0, "widened_blocks": 0, "uncertified_nuclei": 0}
        for _, _, run_counters in per_run:
            for key in counters:
                counters[key] += run_counters[key]
        rows = {
            name: {
                **summarise(np.array([errors[name] for errors, _, _ in per_run])),
                "us_per_pixel": 1e6
                * float(np.median([times[name] for _, times, _ in per_run]))
                / size**2,
            }
            for name in names
        }
        by_n[str(n)] = {"estimators": rows, "counters": counters}
    return by_n


# ---------------------------------------------------------------------------------------------
# Reports


def report_markdown(results: dict) -> str:
    lines = [
        f"# Image-level tessellation study ({results['size']}^2 pixels, "
        f"{results['runs']} runs per n)",
        "",
        f"Seed {results['seed']}; tasks of {results['runs_per_task']} runs on: "
        f"{results['executor']} (times measured there).",
        "",
        "bias +- standard error, std (per pixel, RMS over pixels), us per pixel estimate.",
        "",
    ]
    for n, block in results["by_n"].items():
        lines += [
            f"## n = {n}",
            "",
            "| estimator | us/px | "
            + " | ".join(f"{f} bias +- se | {f} std" for f in FUNCTIONS)
            + " |",
            "|---|---|" + "---|---|" * len(FUNCTIONS),
        ]
        for name, row in block["estimators"].items():
            cells = [
                f"{row['bias'][i]:+.1e} +- {row['se'][i]:.1e} | {row['std'][i]:.3g}"
                for i in range(len(FUNCTIONS))
            ]
            lines.append(f"| {name} | {row['us_per_pixel']:.0f} | " + " | ".join(cells) + " |")
        lines += ["", f"counters: {block['counters']}", ""]
    return "\n".join(lines)


def plot(results: dict, path: Path) -> None:
    names = IMAGE_ESTIMATORS + PIXEL_ESTIMATORS
    ns = [int(n) for n in results["by_n"]]
    fig, axes = plt.subplots(1, len(FUNCTIONS) + 1, figsize=(4 * (len(FUNCTIONS) + 1), 3.6))
    for i, function in enumerate(FUNCTIONS):
        ax = axes[i]
        for name in names:
            std = [results["by_n"][str(n)]["estimators"][name]["std"][i] for n in ns]
            ax.loglog(ns, std, "o-" if name in IMAGE_ESTIMATORS else ".--", label=name)
        ax.set_title(f"{function}: std per pixel")
        ax.set_xlabel("n")
    ax = axes[-1]
    for name in names:
        us = [results["by_n"][str(n)]["estimators"][name]["us_per_pixel"] for n in ns]
        ax.loglog(ns, us, "o-" if name in IMAGE_ESTIMATORS else ".--", label=name)
    ax.set_title("us per pixel estimate")
    ax.set_xlabel("n")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="8 x 8 pixels, 4 runs")
    parser.add_argument("--out", type=Path, default=Path("bench/results/image_tessellation"))
    parser.add_argument("--runs", type=int, default=None, help="runs per n (default 24)")
    parser.add_argument("--size", type=int, default=None, help="image side (default 16)")
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument(
        "--runs-per-task",
        type=positive_int,
        default=1,
        help="runs per task (default 1; the numbers do not depend on it)",
    )
    add_executor_options(parser)
    args = parser.parse_args(argv)
    size = args.size or (8 if args.quick else 16)
    runs = args.runs or (4 if args.quick else 24)
    start = time.perf_counter()
    before = machine()
    with executor_from_args(args) as executor:
        by_n = study_ns(size, runs, args.seed, executor, args.runs_per_task)
    results = {
        "size": size,
        "runs": runs,
        "functions": FUNCTIONS,
        "seed": args.seed,
        "runs_per_task": args.runs_per_task,
        "executor": executor_label(args),
        "by_n": by_n,
        "machine_before": before,
        "machine_after": machine(),
    }
    print(f"{len(NS)} n x {runs} runs: {time.perf_counter() - start:.1f} s", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    (args.out / "report.md").write_text(report_markdown(results))
    plot(results, args.out / "study.png")
    print(report_markdown(results))
    print(f"wrote {args.out}/results.json, report.md, study.png")


if __name__ == "__main__":
    main()
