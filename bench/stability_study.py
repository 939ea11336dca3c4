"""Stability study of the pixel estimators and their failure atlas: where each one is worse
than plain Monte Carlo.

    python bench/stability_study.py [--quick] [--out DIR] [--seed S] [--task-blocks K]
                                    [--workers N | --scheduler ADDRESS]

Where and how each estimator of clrender.estimators misbehaves, measured against exact pixel
integrals: small n (Poisson N = 0 and near-empty pixels), the rejection frequency against the
paper's bound 4 pi n^2 eps^2 exp(-pi n eps^2), fvor with an empty filtered set, a forced
rejection storm (eps far too small), the infinite-variance discontinuity function, fireflies
(one sample multiplied by a large gain) and flat pixels (f == 1).

Sample sets: the SPPP estimators (mc, mc_n, vor, vor_sn, fvor) use the NumPy SPPP generator
(clrender.sppp.draw_sppp; rejected pixels redrawn by clrender.estimators.estimate_with_redraw);
cvor and pvor use N = n uniform points, and so does the baseline of the atlas, mc/independent:
the standard Monte Carlo mean of n uniform samples. Every chart and table names an estimator
with its samples (mc/sppp: mc over SPPP draws, sum / n; mc/independent: the baseline), so the
atlas's first column and its baseline are told apart. All test functions are value columns of the
same draws, so each tessellation serves all of them.

Blocks: the heavy measurements (the pixels of every n, fvor's empty filter, the rejection
frequencies: nearly all of the study's time) are blocks of about BLOCK_POINTS points, each drawn
from its own random stream (seed, section, n [, alpha], first pixel of the block) and estimated
alone (one redraw driver call), so a pixel's numbers depend on its block only. Blocks run as
tasks of --task-blocks blocks on the executor of --workers N (a Dask LocalCluster of N
processes) or --scheduler ADDRESS, this process by default, all sections in one map; every
number is bit-identical whatever the executor and the split (tests/test_cluster_studies.py).
The storm (a few seconds) runs here, from its own streams; the bootstrap intervals draw from
the seed's stream. The per-n seconds are the blocks' own, summed, where they ran. (Before the
executor all sections drew from one stream in order, so this version's draws, and with them
every number, differ from that version's; the statistics are the same.)

Outputs (default bench/results/stability/): results.json (every number), estimates.npz (the
raw per-pixel estimates), report.md (the failure atlas and one section per situation) and the
PNG charts it embeds.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from analytic_study import FUNCTIONS  # noqa: E402
from bootstrap import ratio_interval  # noqa: E402
from common import (  # noqa: E402
    add_executor_options,
    executor_from_args,
    executor_label,
    machine,
    positive_int,
)
from figures import caption, draw_caption, report_caption  # noqa: E402
from matplotlib.ticker import LogFormatter  # noqa: E402
from scipy.stats import beta  # noqa: E402

from clrender.analytic import SmoothSines, StepEdge  # noqa: E402
from clrender.cluster import LocalExecutor  # noqa: E402
from clrender.errors import ClrenderError  # noqa: E402
from clrender.estimators import estimate, estimate_all, estimate_with_redraw  # noqa: E402
from clrender.estimators.qhull_cells import sppp_cells  # noqa: E402
from clrender.samples import SampleSets  # noqa: E402
from clrender.sppp import auxiliary_count, draw_sppp, rejection_bound, sppp_eps  # noqa: E402

SPPP_NAMES = ["mc", "mc_n", "vor", "vor_sn", "fvor"]
UNIFORM_NAMES = ["cvor", "pvor"]
ROW_NAMES = SPPP_NAMES + UNIFORM_NAMES
BASELINE = "mc/independent"  # the mean of n uniform samples


def display(name: str) -> str:
    """An estimator's name with its samples, as the other benches label configurations:
    "<estimator>/sppp" over SPPP draws, "<estimator>/independent" over n uniform points, and
    the baseline (mc over n uniform points) as mc/independent."""
    if name == "baseline":
        return BASELINE
    return f"{name}/sppp" if name in SPPP_NAMES else f"{name}/independent"


def displayed(names) -> list[str]:
    return [display(name) for name in names]


# Points drawn per block (see "Blocks" in the module's docstring): its pixels are drawn from
# their own random stream and estimated together (one redraw driver call of the size the
# study's calls had before the executor).
BLOCK_POINTS = 200_000
EXACT_TOL = 1e-12
BOOT_REPS = 1000
FIREFLY_GAINS = (10, 100, 1_000, 10_000, 100_000, 1_000_000)
REJECTION_BOUNDS = (0.9, 0.3, 0.1, 0.01, 0.001)
STORM_N, STORM_EPS = 16, 1e-4
# name -> driver options of estimate_with_redraw; "defaults" keeps the driver's own values.
STORM_DRIVERS = {
    "defaults, on_exhausted=mc": {"on_exhausted": "mc"},
    "factor 1.5, max_rounds 40": {"max_rounds": 40},
    "factor 2, max_rounds 24": {"enlarge_factor": 2.0, "max_rounds": 24},
}
STORM_ATLAS_DRIVER = "factor 1.5, max_rounds 40"  # the defaults with enough rounds to recover

# A smooth pixel and an edge pixel: the analytic images' functions over image pixel (0, 0).
_SMOOTH = SmoothSines(kx=2.0 * math.pi / 3.7, ky=2.0 * math.pi / 5.3)
_EDGE = StepEdge(x0=0.637, y0=0.5, slope=0.364)


def _local(function):
    """f of pixel-local (u, v) in W, evaluated at image position (1/2 + u, 1/2 + v)."""
    return lambda u, v: function.value(u + 0.5, v + 0.5)


def _flat(u, v):
    return np.ones_like(u)


# name -> (f of pixel-local positions, exact integral over W)
BASE_FUNCTIONS = {
    "flat": (_flat, 1.0),
    "smooth": (_local(_SMOOTH), float(_SMOOTH.pixel_integrals(1, 1)[0, 0])),
    "edge": (_local(_EDGE), float(_EDGE.pixel_integrals(1, 1)[0, 0])),
    "holder_1": FUNCTIONS["holder_1"],
    "discontinuity": FUNCTIONS["discontinuity"],
}
FIREFLY_COLUMNS = [f"firefly_x{g}" for g in FIREFLY_GAINS]
# "firefly_weight" is 1 at the firefly sample, 0 elsewhere: its estimate is that sample's weight.
COLUMNS = [*BASE_FUNCTIONS, "firefly_weight", *FIREFLY_COLUMNS]
EXACT = np.array(
    [e for _, e in BASE_FUNCTIONS.values()]
    + [math.nan]
    + [BASE_FUNCTIONS["smooth"][1]] * len(FIREFLY_GAINS)
)


def col(name: str) -> int:
    return COLUMNS.index(name)


def evaluate_columns(positions: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(T, len(COLUMNS)) values. The firefly of a pixel is its first sample (a uniform one)."""
    u, v = positions[:, 0], positions[:, 1]
    first = np.zeros(len(positions), bool)
    first[offsets[:-1][np.diff(offsets) > 0]] = True
    base = [f(u, v) for f, _ in BASE_FUNCTIONS.values()]
    smooth = base[list(BASE_FUNCTIONS).index("smooth")]
    fireflies = [smooth * np.where(first, gain, 1.0) for gain in FIREFLY_GAINS]
    return np.column_stack([*base, first.astype(np.float64), *fireflies])


# ---------------------------------------------------------------------------------------------
# The engine: many independent pixels at one intensity n


@dataclass
class Runs:
    """Per-pixel estimates (R, len(COLUMNS)) of every estimator at intensity n."""

    n: int
    estimates: dict[str, np.ndarray]  # ROW_NAMES plus "baseline"
    counts: np.ndarray  # (R,) N of each accepted SPPP draw
    redraw: dict = field(default_factory=dict)
    seconds: float = 0.0


REDRAW_SUMS = (
    "redraws",
    "exhausted_pixels",
    "empty_filtered",
    "empty_pixels",
    "recomputed_pixels",
    "qhull_calls",
)
REDRAW_MAXIMA = ("rounds", "eps_enlargements")


def add_redraw_stats(total: dict, stats) -> None:
    for key in REDRAW_SUMS:
        total[key] = total.get(key, 0) + getattr(stats, key)
    for key in REDRAW_MAXIMA:
        total[key] = max(total.get(key, 0), getattr(stats, key))
    total["final_eps"] = max(total.get("final_eps", 0.0), stats.final_eps)


def sppp_draw(rng, n: float, counts: np.ndarray, accept_eps: np.ndarray):
    """The draw for the driver (sample sets and their values); it records N and eps of each
    pixel's last draw, which is its accepted one (rejected pixels are drawn again, accepted
    ones never)."""

    def draw(pixel_ids, eps):
        accept_eps[pixel_ids] = eps
        samples = draw_sppp(rng, n, len(pixel_ids), eps=eps)
        counts[pixel_ids] = samples.counts
        return samples, evaluate_columns(samples.traced, samples.offsets)

    return draw


# ---------------------------------------------------------------------------------------------
# Blocks: the measurements as tasks of an executor (bench/common.py --workers / --scheduler)


# The random streams of the measurements: (seed, section, key..., first pixel of the block)
STREAM_SPPP, STREAM_UNIFORM, STREAM_FVOR, STREAM_REJECTION, STREAM_STORM = range(1, 6)


@dataclass(frozen=True)
class Block:
    """Pixels [start, start + count) of one measurement, drawn from the random stream
    (*stream, start) alone: plain data for a task. kind: "sppp" (SPPP estimators through the
    redraw driver, options `driver`), "uniform" (baseline, cvor and pvor on n uniform points),
    "fvor" (fvor's empty filtered set) or "rejection" (first-draw rejections at eps)."""

    kind: str
    n: int
    start: int
    count: int
    stream: tuple[int, ...]
    eps: float | None = None
    names: tuple[str, ...] = tuple(SPPP_NAMES)
    driver: tuple[tuple[str, object], ...] = ()

    def rng(self) -> np.random.Generator:
        return np.random.default_rng([*self.stream, self.start])


def blocks_of(kind: str, n: int, pixels: int, stream, points_per_pixel: int, **fields) -> list:
    """The blocks of `pixels` pixels of a measurement: BLOCK_POINTS points each."""
    per_block = max(1, BLOCK_POINTS // points_per_pixel)
    return [
        Block(kind, n, start, min(per_block, pixels - start), tuple(stream), **fields)
        for start in range(0, pixels, per_block)
    ]


def sppp_blocks(n: int, pixels: int, stream, eps=None, names=SPPP_NAMES, **driver) -> list:
    points = n + auxiliary_count(n, eps or sppp_eps(n))
    return blocks_of(
        "sppp",
        n,
        pixels,
        stream,
        points,
        eps=eps,
        names=tuple(names),
        driver=tuple(sorted(driver.items())),
    )


def run_block(block: Block):
    """A block's measurement (see Block), and the seconds it took where it ran."""
    start = time.perf_counter()
    rng = block.rng()
    if block.kind == "sppp":
        counts, accept_eps = np.zeros(block.count, np.int64), np.zeros(block.count)
        draw = sppp_draw(rng, block.n, counts, accept_eps)
        outcome = estimate_with_redraw(
            list(block.names), draw, block.count, block.n, eps=block.eps, **dict(block.driver)
        )
        result = (outcome.estimates, counts, accept_eps, outcome.stats)
    elif block.kind == "uniform":
        positions = rng.random((block.count * block.n, 2)) - 0.5
        offsets = np.arange(block.count + 1, dtype=np.int64) * block.n
        samples = SampleSets(positions, offsets, float(block.n))
        results = estimate_all(
            ["mc", *UNIFORM_NAMES], samples, evaluate_columns(positions, offsets)
        )
        result = {
            "baseline": results["mc"].estimates,
            **{name: results[name].estimates for name in UNIFORM_NAMES},
        }
    elif block.kind == "fvor":
        result = fvor_empty_row(block.n, block.count, rng)
    else:  # rejection
        batch = draw_sppp(rng, block.n, block.count, eps=block.eps)
        result = int(estimate("vor", batch, np.ones(len(batch.traced))).needs_redraw.sum())
    return result, time.perf_counter() - start


def run_task(blocks: list[Block]) -> list:
    """One task: its blocks, in order."""
    return [run_block(block) for block in blocks]


def run_blocks(blocks: list[Block], executor=None, task_blocks: int = 1) -> list:
    """[(result, seconds)] of every block, in order, from tasks of task_blocks consecutive
    blocks on the executor (this process by default): the same numbers for any split."""
    tasks = [blocks[k : k + task_blocks] for k in range(0, len(blocks), task_blocks)]
    results: list = [None] * len(tasks)
    for index, result in (executor or LocalExecutor()).map(run_task, tasks):
        results[index] = result
    return [result for task in results for result in task]


def joined_sppp(results: list) -> tuple[dict, np.ndarray, np.ndarray, dict]:
    """The sppp blocks' results as one: estimates per estimator, N and accepting eps of each
    pixel, and the redraw statistics."""
    stats: dict = {}
    for (_, _, _, block_stats), _ in results:
        add_redraw_stats(stats, block_stats)
    estimates = {
        name: np.concatenate([r[0][name] for r, _ in results]) for name in results[0][0][0]
    }
    counts = np.concatenate([r[1] for r, _ in results])
    accept_eps = np.concatenate([r[2] for r, _ in results])
    return estimates, counts, accept_eps, stats


def run_sppp(n: int, runs: int, stream, executor=None, names=SPPP_NAMES, **driver):
    """SPPP estimates of `runs` pixels through the redraw driver (driver options passed on)."""
    eps = driver.pop("eps", None)
    return joined_sppp(run_blocks(sppp_blocks(n, runs, stream, eps, names, **driver), executor))


def runs_of(n: int, sppp: list, uniform: list) -> Runs:
    """An n's Runs from its sppp and uniform blocks' results; seconds: the blocks' own."""
    estimates, counts, _, stats = joined_sppp(sppp)
    for name in ["baseline", *UNIFORM_NAMES]:
        estimates[name] = np.concatenate([r[name] for r, _ in uniform])
    seconds = sum(t for _, t in sppp) + sum(t for _, t in uniform)
    return Runs(n, estimates, counts, stats, seconds)


# ---------------------------------------------------------------------------------------------
# Statistics


def rmse(errors: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.sqrt(np.mean(errors**2, axis=axis))


def median_abs(errors: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.median(np.abs(errors), axis=axis)


METRICS = {"RMSE": rmse, "median |error|": median_abs}


def ratio_ci(errors: np.ndarray, base: np.ndarray, metric: str, rng, paired: bool) -> dict:
    """metric(errors) / metric(base) with a 95 % percentile bootstrap interval (bench/bootstrap.py);
    paired: the i-th errors and base errors come from the same draws, resampled jointly."""
    stat = METRICS[metric]
    value, base_value = float(stat(errors)), float(stat(base))
    out = {"metric": metric, "value": value, "baseline": base_value}
    if base_value <= EXACT_TOL:
        return {
            **out,
            "ratio": math.inf if value > EXACT_TOL else 1.0,
            "lo": math.nan,
            "hi": math.nan,
        }
    ratio, lo, hi = ratio_interval(errors, base, stat, rng, paired=paired, resamples=BOOT_REPS)
    return {**out, "ratio": ratio, "lo": lo, "hi": hi}


def verdict(r: dict) -> str:
    if r["baseline"] <= EXACT_TOL:
        return "same (both exact)" if r["value"] <= EXACT_TOL else f"worse ({BASELINE} exact)"
    if r["lo"] > 1.0:
        return "worse"
    return "better" if r["hi"] < 1.0 else "same"


def describe(estimates: np.ndarray, exact: float) -> dict:
    """Location, spread (std and robust) and tail of one estimator's per-pixel estimates."""
    errors = estimates - exact
    q25, q50, q75 = np.percentile(estimates, [25, 50, 75])
    runs = len(estimates)
    std = float(estimates.std(ddof=1))
    return {
        "mean": float(estimates.mean()),
        "bias": float(errors.mean()),
        "se": std / math.sqrt(runs),
        "std": std,
        "rmse": float(rmse(errors)),
        "median": float(q50),
        "iqr": float(q75 - q25),
        "mad": float(np.median(np.abs(estimates - q50))),
        "median_abs_error": float(median_abs(errors)),
        "max_abs_error": float(np.abs(errors).max()),
        "largest": np.sort(estimates)[-5:][::-1].tolist(),
        "runs": runs,
    }


def upper_95(k: int, trials: int) -> float:
    """One-sided 95 % Clopper-Pearson upper bound of a binomial proportion."""
    return 1.0 if k >= trials else float(beta.ppf(0.95, k + 1, trials - k))


# ---------------------------------------------------------------------------------------------
# Sections


def small_n_section(all_runs: dict[int, Runs]) -> dict:
    """Per n: Poisson N = 0 and near-empty frequencies; bias and RMSE ratio on the smooth pixel."""
    rows = []
    c, exact = col("smooth"), EXACT[col("smooth")]
    for n, runs in all_runs.items():
        base = runs.estimates["baseline"][:, c] - exact
        row = {
            "n": n,
            "pixels": len(runs.counts),
            "p_empty": float((runs.counts == 0).mean()),
            "p_empty_poisson": math.exp(-n),
            "estimators": {},
        }
        for k in (1, 2, 3):
            row[f"p_N{k}"] = float((runs.counts == k).mean())
        for name in ROW_NAMES:
            d = describe(runs.estimates[name][:, c], exact)
            d["rmse_ratio"] = d["rmse"] / float(rmse(base))
            row["estimators"][name] = d
        row["baseline"] = describe(runs.estimates["baseline"][:, c], exact)
        rows.append(row)
    return {"function": "smooth", "rows": rows}


def near_empty_section(runs: Runs) -> dict:
    """SPPP estimators conditioned on N (0, 1, 2, 3, >= 4) at one small n, smooth pixel."""
    c, exact = col("smooth"), EXACT[col("smooth")]
    classes = {
        "0": runs.counts == 0,
        "1": runs.counts == 1,
        "2": runs.counts == 2,
        "3": runs.counts == 3,
        ">=4": runs.counts >= 4,
    }
    table = {}
    for label, mask in classes.items():
        table[label] = {"pixels": int(mask.sum())}
        for name in SPPP_NAMES:
            values = runs.estimates[name][mask, c]
            table[label][name] = (
                {
                    "finite": bool(np.isfinite(values).all()),
                    "mean_error": float(values.mean() - exact),
                    "rms_error": float(rmse(values - exact)),
                    "max_abs": float(np.abs(values).max()),
                }
                if mask.any()
                else None
            )
    return {"n": runs.n, "function": "smooth", "classes": table}


def fvor_empty_row(n: int, pixels: int, rng) -> dict:
    """How often fvor's filtered set is empty (no W cell inside W') and what it returns then."""
    c, exact = col("smooth"), EXACT[col("smooth")]
    batch = draw_sppp(rng, n, pixels)
    values = evaluate_columns(batch.traced, batch.offsets)[:, c]
    results = estimate_all(["vor_sn", "fvor"], batch, values)
    cells = sppp_cells(batch.traced, batch.offsets, batch.aux, batch.aux_offsets, 0.5 + batch.eps)
    counts = batch.counts
    pixel = np.repeat(np.arange(pixels), counts)
    kept = np.bincount(pixel, cells.inside_box & cells.bounded, pixels)
    valid = ~results["fvor"].needs_redraw & (counts > 0)
    empty = valid & (kept == 0)
    fvor, vor_sn = results["fvor"].estimates, results["vor_sn"].estimates
    return {
        "n": n,
        "pixels": pixels,
        "eps": batch.eps,
        "valid_nonempty": int(valid.sum()),
        "empty_filtered": int(empty.sum()),
        "frequency": float(empty.sum() / valid.sum()),
        "stats_empty_filtered": results["fvor"].stats.empty_filtered,
        "max_abs_fvor_minus_vor_sn": float(np.abs(fvor[empty] - vor_sn[empty]).max())
        if empty.any()
        else None,
        "mean_N_when_empty": float(counts[empty].mean()) if empty.any() else None,
        "rms_error_empty": float(rmse(fvor[empty] - exact)) if empty.any() else None,
        "rms_error_kept": float(rmse(fvor[valid & ~empty] - exact)),
    }


def rejection_row(n: int, alpha: float, pixels: int, results: list) -> dict:
    """First-draw rejection frequency (a W nucleus with an unbounded cell) at eps(n, alpha),
    from the rejection blocks' counts."""
    eps = sppp_eps(n, alpha)
    rejected = sum(count for count, _ in results)
    return {
        "n": n,
        "alpha": alpha,
        "eps": eps,
        "n_aux": auxiliary_count(n, eps),
        "bound": rejection_bound(n, eps),
        "pixels": pixels,
        "rejected": rejected,
        "frequency": rejected / pixels,
        "upper_95": upper_95(rejected, pixels),
    }


def rejection_blocks(n: int, alpha_index: int, pixels: int, seed: int) -> list[Block]:
    eps = sppp_eps(n, REJECTION_BOUNDS[alpha_index])
    stream = (seed, STREAM_REJECTION, n, alpha_index)
    return blocks_of("rejection", n, pixels, stream, n + auxiliary_count(n, eps), eps=eps)


def storm_run(label: str, pixels: int, stream, driver: dict) -> dict:
    start = time.perf_counter()
    estimates, counts, accept_eps, stats = run_sppp(
        STORM_N, pixels, stream, eps=STORM_EPS, **driver
    )
    seconds = time.perf_counter() - start
    summary = {}
    for fname in ("holder_1", "smooth"):
        c = col(fname)
        summary[fname] = {name: describe(e[:, c], EXACT[c]) for name, e in estimates.items()}
        for d in summary[fname].values():
            d["z"] = d["bias"] / d["se"] if d["se"] > 0 else math.inf
    by_eps = storm_by_eps(estimates, accept_eps)
    return {
        "label": label,
        "driver": driver,
        "pixels": pixels,
        "seconds": seconds,
        "redraw": stats,
        "summary": summary,
        "by_accept_eps": by_eps,
        "holder_1": {k: v[:, col("holder_1")] for k, v in estimates.items()},
    }


def storm_by_eps(estimates: dict, accept_eps: np.ndarray) -> list[dict]:
    """Bias on holder_1 of the pixels accepted at each eps, with the paper's bound there."""
    rows = []
    c, exact = col("holder_1"), EXACT[col("holder_1")]
    for eps in np.unique(accept_eps):
        mask = accept_eps == eps
        row = {
            "eps": float(eps),
            "pixels": int(mask.sum()),
            "bound": rejection_bound(STORM_N, float(eps)),
            "n_aux": auxiliary_count(STORM_N, float(eps)),
        }
        for name, e in estimates.items():
            row[name] = float(e[mask, c].mean() - exact)
        rows.append(row)
    return rows


def storm_section(pixels: int, seed: int) -> dict:
    """The storm, in this process (a few seconds): each driver's pixels from their own stream."""
    runs = {
        label: storm_run(label, pixels, (seed, STREAM_STORM, index), dict(driver))
        for index, (label, driver) in enumerate(STORM_DRIVERS.items())
    }
    try:
        run_sppp(STORM_N, 20, (seed, STREAM_STORM, len(STORM_DRIVERS)), eps=STORM_EPS)
        raised = None
    except ClrenderError as error:
        raised = str(error)
    return {
        "n": STORM_N,
        "eps": STORM_EPS,
        "paper_eps": sppp_eps(STORM_N),
        "runs": runs,
        "defaults_on_exhausted_raise": raised,
    }


def storm_reference(all_runs: dict[int, Runs]) -> dict | None:
    """holder_1 at n = STORM_N and the paper's eps (no storm), for comparison."""
    if STORM_N not in all_runs:
        return None
    c, exact = col("holder_1"), EXACT[col("holder_1")]
    out = {}
    for name in SPPP_NAMES:
        d = describe(all_runs[STORM_N].estimates[name][:, c], exact)
        out[name] = {**d, "z": d["bias"] / d["se"]}
    return out


def discontinuity_section(all_runs: dict[int, Runs], ns) -> dict:
    c, exact = col("discontinuity"), EXACT[col("discontinuity")]
    return {
        n: {
            name: describe(all_runs[n].estimates[name][:, c], exact)
            for name in [*ROW_NAMES, "baseline"]
        }
        for n in ns
        if n in all_runs
    }


def firefly_section(all_runs: dict[int, Runs], ns) -> dict:
    """RMSE against the gain and the firefly sample's weight, per estimator."""
    out = {}
    exact = EXACT[col("smooth")]
    for n in (n for n in ns if n in all_runs):
        out[n] = {}
        for name in [*ROW_NAMES, "baseline"]:
            e = all_runs[n].estimates[name]
            weights = e[:, col("firefly_weight")]
            out[n][name] = {
                "rmse_by_gain": [float(rmse(e[:, col("smooth")] - exact))]
                + [float(rmse(e[:, col(c)] - exact)) for c in FIREFLY_COLUMNS],
                "finite": bool(np.isfinite(e[:, [col(c) for c in FIREFLY_COLUMNS]]).all()),
                "n_weight_mean": float(n * weights.mean()),
                "n_weight_rms": float(n * np.sqrt((weights**2).mean())),
                "n_weight_max": float(n * weights.max()),
            }
    return {"gains": [1, *FIREFLY_GAINS], "by_n": out}


def flat_section(all_runs: dict[int, Runs]) -> list[dict]:
    """f == 1: the estimators whose weights sum to 1 are exact whenever N >= 1; mc and vor not."""
    rows = []
    c = col("flat")
    for n, runs in all_runs.items():
        row = {"n": n, "estimators": {}}
        nonempty = runs.counts >= 1
        for name in [*ROW_NAMES, "baseline"]:
            e = runs.estimates[name][:, c]
            mask = nonempty if name in SPPP_NAMES else np.ones(len(e), bool)
            row["estimators"][name] = {
                "std": float(e.std(ddof=1)),
                "mean": float(e.mean()),
                "max_abs_error_N_ge_1": float(np.abs(e[mask] - 1).max()),
            }
        rows.append(row)
    return rows


# ---------------------------------------------------------------------------------------------
# The failure atlas


def atlas_situations(ns_available) -> list[tuple[str, int, str, str]]:
    """(label, n, column, metric); situations whose n was not run are left out."""
    situations = [
        ("near-empty: smooth, n = 2", 2, "smooth", "RMSE"),
        ("smooth, n = 4", 4, "smooth", "RMSE"),
        ("smooth, n = 16", 16, "smooth", "RMSE"),
        ("smooth, n = 256", 256, "smooth", "RMSE"),
        ("flat f = 1, n = 2", 2, "flat", "RMSE"),
        ("flat f = 1, n = 16", 16, "flat", "RMSE"),
        ("flat f = 1, n = 256", 256, "flat", "RMSE"),
        ("edge, n = 16", 16, "edge", "RMSE"),
        ("edge, n = 256", 256, "edge", "RMSE"),
        ("holder_1, n = 64", 64, "holder_1", "RMSE"),
        ("discontinuity, n = 64", 64, "discontinuity", "median |error|"),
        ("discontinuity, n = 256", 256, "discontinuity", "median |error|"),
        ("firefly x1e4 (smooth), n = 16", 16, "firefly_x10000", "RMSE"),
        ("firefly x1e4 (smooth), n = 64", 64, "firefly_x10000", "RMSE"),
    ]
    return [s for s in situations if s[1] in ns_available]


def build_atlas(all_runs: dict[int, Runs], storm: dict, rng) -> list[dict]:
    rows = []
    for label, n, column, metric in atlas_situations(all_runs):
        c, exact = col(column), EXACT[col(column)]
        base = all_runs[n].estimates["baseline"][:, c] - exact
        cells = {}
        for name in ROW_NAMES:
            errors = all_runs[n].estimates[name][:, c] - exact
            r = ratio_ci(errors, base, metric, rng, paired=name in UNIFORM_NAMES)
            cells[name] = {**r, "verdict": verdict(r)}
        rows.append(
            {"situation": label, "n": n, "column": column, "metric": metric, "cells": cells}
        )
    if STORM_N in all_runs:
        rows.append(storm_atlas_row(all_runs[STORM_N], storm, rng))
    return rows


def storm_atlas_row(runs: Runs, storm: dict, rng) -> dict:
    label = STORM_ATLAS_DRIVER
    c, exact = col("holder_1"), EXACT[col("holder_1")]
    base = runs.estimates["baseline"][:, c] - exact
    cells = {}
    for name in SPPP_NAMES:
        errors = storm["runs"][label]["holder_1"][name] - exact
        r = ratio_ci(errors, base, "RMSE", rng, paired=False)
        cells[name] = {**r, "verdict": verdict(r)}
    return {
        "situation": f"storm eps {STORM_EPS:g} ({label}): holder_1, n = {STORM_N}",
        "n": STORM_N,
        "column": "holder_1",
        "metric": "RMSE",
        "cells": cells,
    }


# ---------------------------------------------------------------------------------------------
# Charts


def save(fig, out: Path, name: str, tight: bool = True) -> str:
    if tight:
        fig.tight_layout()
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return name


def atlas_caption(config: dict) -> str:
    """The atlas figure's parameters."""
    runs = config["runs"]
    return caption(
        "Failure atlas: error of each estimator over its samples against the baseline's",
        {
            "pixels": "one per run, f integrated over W = [-1/2, 1/2]^2 against its exact integral",
            "runs": ", ".join(f"{r} at n = {n}" for n, r in runs.items()),
            "seed": config["seed"],
            "baseline": f"{BASELINE}, the mean of n uniform samples",
            "columns": "estimator/samples (sppp: Poisson draws redrawn when rejected; "
            "independent: n uniform points, paired with the baseline's)",
            "cells": "error ratio (RMSE, or median |error| where noted) and verdict from its 95 % "
            f"percentile bootstrap interval ({BOOT_REPS} resamples of the runs)",
            "device": "host (NumPy and Qhull, one thread)",
        },
    )


def plot_atlas(atlas: list[dict], out: Path, config: dict) -> str:
    ratios = np.array(
        [
            [row["cells"][name]["ratio"] if name in row["cells"] else np.nan for name in ROW_NAMES]
            for row in atlas
        ]
    )
    shown = np.clip(np.log2(np.where(np.isinf(ratios), 8.0, ratios)), -3, 3)
    fig, ax = plt.subplots(figsize=(13, 0.45 * len(atlas) + 2.5), layout="constrained")
    image = ax.imshow(shown, cmap="RdBu_r", vmin=-3, vmax=3, aspect="auto")
    for i, row in enumerate(atlas):
        for j, name in enumerate(ROW_NAMES):
            cell = row["cells"].get(name)
            if cell is not None:
                text = "inf" if math.isinf(cell["ratio"]) else f"{cell['ratio']:.2g}"
                ax.text(
                    j,
                    i,
                    f"{text}\n{cell['verdict'].split()[0]}",
                    ha="center",
                    va="center",
                    fontsize=6,
                    color="w" if abs(shown[i, j]) > 2 else "k",
                )
    ax.set_xticks(range(len(ROW_NAMES)), [d.replace("/", "/\n") for d in displayed(ROW_NAMES)])
    ax.set_yticks(range(len(atlas)), [row["situation"] for row in atlas], fontsize=7)
    fig.colorbar(image, ax=ax, label=f"log2(error ratio estimator / {BASELINE}), clipped to +-3")
    ax.set_title(f"Failure atlas: error ratio against {BASELINE} (the mean of n uniform samples)")
    draw_caption(fig, atlas_caption(config))
    return save(fig, out, "atlas.png", tight=False)


def draw_fractions(
    ax, x, fractions, trials, label: str, style: str, zero_size: float = 7, **kwargs
) -> None:
    """Measured fractions (count / trials) on a log y axis: the nonzero ones as `style`, lines
    broken at zeros; a zero count (not drawable on a log axis) as a hollow down-triangle of the
    same colour at its 95 % upper bound (the true fraction lies below it), `zero_size` points
    wide (series of one chart take sizes that nest, so coinciding triangles all show)."""
    x, fractions = np.asarray(x, float), np.asarray(fractions, float)
    (line,) = ax.plot(x, np.where(fractions > 0, fractions, np.nan), style, label=label, **kwargs)
    zero = fractions == 0
    bounds = [upper_95(0, t) for t in np.asarray(trials)[zero]]
    ax.plot(x[zero], bounds, "v", mfc="none", ms=zero_size, color=line.get_color())


ZERO_COUNT_LABEL = "0 of N: 95 % upper bound"


def zero_count_legend_entry(ax) -> None:
    """The legend entry of draw_fractions' zero counts (drawn once, in grey)."""
    ax.plot([], [], "v", mfc="none", ms=7, color="0.4", label=ZERO_COUNT_LABEL)


def plot_small_n(small: dict, out: Path) -> str:
    rows = small["rows"]
    ns = [r["n"] for r in rows]
    pixels = [r["pixels"] for r in rows]
    fig, (ax0, ax1, ax2) = plt.subplots(1, 3, figsize=(15, 4.5))
    draw_fractions(
        ax0, ns, [r["p_empty"] for r in rows], pixels, "measured P(N = 0)", "o", zero_size=13
    )
    ax0.plot(ns, [r["p_empty_poisson"] for r in rows], "-", label="exp(-n)")
    for k in (1, 2, 3):
        fractions = [r[f"p_N{k}"] for r in rows]
        draw_fractions(ax0, ns, fractions, pixels, f"P(N = {k})", ".--", zero_size=13 - 3 * k)
    zero_count_legend_entry(ax0)
    # Below one pixel in the largest sample nothing is measurable; exp(-n) runs on below it
    ax0.set(
        xscale="log",
        yscale="log",
        ylim=(0.2 / max(pixels), 1.5),
        xlabel="n",
        ylabel="fraction of pixels",
        title=f"Poisson count of the SPPP draws ({', '.join(map(str, sorted(set(pixels))))} "
        "pixels per n)",
    )
    for name in ROW_NAMES:
        bias = np.array([r["estimators"][name]["bias"] for r in rows])
        se = np.array([r["estimators"][name]["se"] for r in rows])
        ax1.errorbar(ns, bias, yerr=2 * se, marker="o", ms=3, capsize=2, label=display(name))
        ax2.loglog(
            ns,
            [r["estimators"][name]["rmse_ratio"] for r in rows],
            marker="o",
            ms=3,
            label=display(name),
        )
    ax1.axhline(0, color="k", lw=0.8)
    ax1.set(xscale="log", xlabel="n", ylabel="bias +- 2 SE", title="smooth pixel: bias")
    ax2.axhline(1, color="k", lw=0.8, ls="--")
    ax2.set(xlabel="n", ylabel=f"RMSE / RMSE({BASELINE})", title="smooth pixel: RMSE ratio")
    for ax in (ax0, ax1, ax2):
        ax.legend(fontsize=7)
    return save(fig, out, "small_n.png")


def plot_rejection(rows: list[dict], out: Path) -> str:
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 4.8))
    ns = sorted({r["n"] for r in rows})
    cmap = plt.get_cmap("viridis")
    for i, n in enumerate(ns):
        sel = [r for r in rows if r["n"] == n]
        draw_fractions(
            ax0,
            [r["bound"] for r in sel],
            [r["frequency"] for r in sel],
            [r["pixels"] for r in sel],
            f"n = {n}",
            "o-",
            zero_size=11 - 6 * i / max(1, len(ns) - 1),
            ms=3,
            color=cmap(i / max(1, len(ns) - 1)),
        )
    ax0.loglog([1e-3, 1], [1e-3, 1], "k--", lw=0.8, label="frequency = bound")
    zero_count_legend_entry(ax0)
    ax0.set(
        xlabel="paper's bound 4 pi n^2 eps^2 exp(-pi n eps^2)",
        ylabel="measured rejection frequency",
        title="Rejection frequency against the bound",
    )
    ax0.legend(fontsize=6, ncol=2)
    alpha = min(REJECTION_BOUNDS)
    sel = [r for r in rows if r["alpha"] == alpha]
    measured = [r for r in sel if r["rejected"] > 0]
    if measured:
        ax1.plot(
            [r["n"] for r in measured], [r["frequency"] for r in measured], "o", label="measured"
        )
    ax1.plot([r["n"] for r in sel], [r["upper_95"] for r in sel], "v", label="95 % upper bound")
    for r in sel:
        if r["rejected"] == 0:
            ax1.annotate(
                f"0 of {r['pixels']}",
                (r["n"], r["upper_95"]),
                xytext=(0, -14),
                textcoords="offset points",
                ha="center",
                fontsize=7,
            )
    ax1.axhline(alpha, color="k", ls="--", lw=0.8, label="bound = alpha")
    ax1.set(
        xscale="log",
        yscale="log",
        xlabel="n",
        ylabel="rejection frequency (no dot: 0 rejected)",
        title=f"At the default eps (bound {alpha:g})",
    )
    ax1.margins(x=0.1, y=0.15)
    plain_log_labels(ax1.yaxis)
    ax1.legend(fontsize=7)
    return save(fig, out, "rejection.png")


def plot_storm(storm: dict, out: Path) -> str:
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 4.5))
    labels = list(storm["runs"])
    width = 0.8 / len(labels)
    for i, label in enumerate(labels):
        z = [storm["runs"][label]["summary"]["holder_1"][name]["z"] for name in SPPP_NAMES]
        ax0.bar(np.arange(len(SPPP_NAMES)) + i * width, np.clip(z, -60, 60), width, label=label)
    if storm["reference"] is not None:
        z = [storm["reference"][name]["z"] for name in SPPP_NAMES]
        ax0.plot(np.arange(len(SPPP_NAMES)) + 0.4, z, "kD", label="paper's eps, no storm")
    ax0.axhspan(-4, 4, color="g", alpha=0.15, label="|z| < 4")
    ax0.set_xticks(np.arange(len(SPPP_NAMES)) + 0.4, SPPP_NAMES)
    ax0.set(ylabel="bias / SE (clipped to +-60)", title="Storm: holder_1 bias in SE")
    ax0.legend(fontsize=7)
    rows = storm["runs"][STORM_ATLAS_DRIVER]["by_accept_eps"]
    ax1.bar(range(len(rows)), [r["pixels"] for r in rows])
    ax1.set_xticks(
        range(len(rows)), [f"{r['eps']:.3g}\nb={r['bound']:.2g}" for r in rows], fontsize=6
    )
    ax1.set(
        xlabel="eps at acceptance (b = paper's bound there)",
        ylabel="pixels",
        title=f"Storm (factor 1.5): paper's eps = {storm['paper_eps']:.3f}",
    )
    return save(fig, out, "storm.png")


def plot_discontinuity(disc: dict, all_runs: dict[int, Runs], out: Path) -> str:
    n = max(disc)
    c, exact = col("discontinuity"), EXACT[col("discontinuity")]
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 4.5))
    for name in [*ROW_NAMES, "baseline"]:
        errors = np.sort(np.abs(all_runs[n].estimates[name][:, c] - exact))
        survival = 1.0 - np.arange(len(errors)) / len(errors)
        ax0.loglog(errors, survival, lw=1, label=display(name))
    ax0.set(
        xlabel="|estimate - exact|",
        ylabel="fraction of pixels with a larger error",
        title=f"discontinuity, n = {n}: error tails",
    )
    ax0.legend(fontsize=7)
    names = list(disc[n])
    x = np.arange(len(names))
    for offset, key, label in (
        (-0.3, "std", "std"),
        (-0.1, "iqr", "IQR"),
        (0.1, "mad", "MAD"),
        (0.3, "median_abs_error", "median |error|"),
    ):
        ax1.bar(x + offset, [disc[n][m][key] for m in names], 0.2, label=label)
    ax1.set_xticks(x, names, fontsize=7)
    ax1.set(yscale="log", title=f"discontinuity, n = {n}: spread")
    ax1.legend(fontsize=7)
    return save(fig, out, "discontinuity.png")


class PlainLogFormatter(LogFormatter):
    """LogFormatter's choice of the ticks to label, each labelled as a plain number (2, 0.01)
    rather than 2x10^0."""

    def __call__(self, value, pos=None):
        return f"{value:g}" if super().__call__(value, pos) else ""


def plain_log_labels(axis) -> None:
    """Plain tick labels on a log axis; ticks between decades labelled only where the axis
    spans too few decades for its own (matplotlib's rule)."""
    axis.set_major_formatter(PlainLogFormatter())
    axis.set_minor_formatter(PlainLogFormatter(labelOnlyBase=False))


def plot_fireflies(fire: dict, out: Path) -> str:
    ns = list(fire["by_n"])
    fig, axes = plt.subplots(1, len(ns) + 1, figsize=(5 * (len(ns) + 1), 4.5))
    for ax, n in zip(axes, ns, strict=False):
        base = np.array(fire["by_n"][n]["baseline"]["rmse_by_gain"])
        for name in ROW_NAMES:
            ratio = np.array(fire["by_n"][n][name]["rmse_by_gain"]) / base
            ax.loglog(fire["gains"], ratio, marker="o", ms=3, label=display(name))
        ax.axhline(1, color="k", lw=0.8, ls="--")
        ax.set(
            xlabel="firefly gain (1 = no firefly)",
            ylabel=f"RMSE / RMSE({BASELINE})",
            title=f"smooth pixel, one firefly, n = {n}",
        )
        plain_log_labels(ax.yaxis)
        ax.legend(fontsize=7)
    n = ns[-1]
    names = list(fire["by_n"][n])
    labels = displayed(names)
    axes[-1].bar(labels, [fire["by_n"][n][m]["n_weight_rms"] for m in names], label="rms")
    axes[-1].plot(
        labels, [fire["by_n"][n][m]["n_weight_max"] for m in names], "v", color="C3", label="max"
    )
    axes[-1].set(
        yscale="log",
        ylabel="n x weight of the firefly sample (rms, max)",
        title=f"firefly weight, n = {n}",
    )
    plain_log_labels(axes[-1].yaxis)
    axes[-1].tick_params(axis="x", labelsize=7, labelrotation=30)
    plt.setp(axes[-1].get_xticklabels(), ha="right", rotation_mode="anchor")
    axes[-1].legend(fontsize=7)
    return save(fig, out, "fireflies.png")


def plot_flat(flat: list[dict], out: Path) -> str:
    ns = np.array([r["n"] for r in flat])
    # The log axis above; below it a strip of the stds that are exactly 0 (off any log axis)
    fig, (ax, zero_ax) = plt.subplots(
        2, 1, figsize=(6.5, 5.2), sharex=True, gridspec_kw={"height_ratios": (5, 1.3)}
    )
    exact = []  # display names of the series with an std of exactly 0 at some n
    for name in ROW_NAMES + ["baseline"]:
        std = np.array([r["estimators"][name]["std"] for r in flat])
        (line,) = ax.plot(ns, np.where(std > 0, std, np.nan), marker="o", ms=3, label=display(name))
        if (std == 0).any():
            zero_ax.plot(
                ns[std == 0],
                [len(exact)] * int((std == 0).sum()),
                "o",
                ms=4,
                color=line.get_color(),
            )
            exact.append(display(name))
    ax.plot(ns, [n**-0.5 for n in ns], "k--", lw=0.8, label="1 / sqrt(n)")
    ax.set(yscale="log", ylabel="std on f == 1", title="Flat pixel: noise added by the estimator")
    ax.legend(fontsize=7)
    zero_ax.set_yticks(range(len(exact)), exact, fontsize=6)
    zero_ax.set(xscale="log", xlabel="n", ylim=(-0.7, max(len(exact), 1) - 0.3))
    zero_ax.set_ylabel("std = 0", fontsize=8)
    return save(fig, out, "flat.png")


# ---------------------------------------------------------------------------------------------
# Report


def fmt(x: float) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    if isinstance(x, float) and math.isinf(x):
        return "inf"
    return f"{x:.3g}"


def table(header: list[str], rows: list[list]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines


def atlas_markdown(atlas: list[dict]) -> list[str]:
    rows = []
    for row in atlas:
        cells = []
        for name in ROW_NAMES:
            cell = row["cells"].get(name)
            if cell is None:
                cells.append("n/a")
            elif cell["verdict"].endswith("exact)"):
                cells.append(f"{cell['verdict']} ({fmt(cell['value'])} vs {fmt(cell['baseline'])})")
            else:
                cells.append(
                    f"**{cell['verdict']}** {fmt(cell['ratio'])} "
                    f"[{fmt(cell['lo'])}, {fmt(cell['hi'])}]"
                )
        rows.append([row["situation"], row["metric"], *cells])
    return table(["situation", "metric", *displayed(ROW_NAMES)], rows)


def ratio_text(cell: dict) -> str:
    if math.isinf(cell["ratio"]):
        return f"{cell['metric']} {fmt(cell['value'])} where {BASELINE} is exact"
    return f"{fmt(cell['ratio'])}x"


def worse_than_mc_markdown(atlas: list[dict]) -> list[str]:
    lines = []
    for name in ROW_NAMES:
        worse = [
            f"{row['situation']} ({ratio_text(row['cells'][name])})"
            for row in atlas
            if name in row["cells"] and row["cells"][name]["verdict"].startswith("worse")
        ]
        lines.append(
            f"- **{display(name)}**: " + ("; ".join(worse) if worse else "never worse here")
        )
    return lines


def small_n_markdown(small: dict, near: dict, fvor_rows: list[dict]) -> list[str]:
    counts = [
        [
            r["n"],
            r["pixels"],
            fmt(r["p_empty"]),
            fmt(r["p_empty_poisson"]),
            fmt(r["p_N1"]),
            fmt(r["p_N2"]),
            fmt(r["p_N3"]),
        ]
        for r in small["rows"]
    ]
    lines = [
        "### Poisson counts of the SPPP draws",
        "",
        *table(["n", "pixels", "P(N = 0)", "exp(-n)", "P(N = 1)", "P(N = 2)", "P(N = 3)"], counts),
        "",
        f"### Smooth pixel: bias (z = bias / SE) and RMSE ratio against {BASELINE}",
        "",
    ]

    def bias_cell(measured: dict) -> str:
        z = measured["bias"] / measured["se"]
        return f"{fmt(measured['bias'])} (z {z:+.1f}); {fmt(measured['rmse_ratio'])}"

    rows = [[r["n"], *[bias_cell(r["estimators"][m]) for m in ROW_NAMES]] for r in small["rows"]]
    lines += table(["n", *displayed(ROW_NAMES)], rows)
    lines += [
        "",
        f"### Near-empty pixels at n = {near['n']} (SPPP estimators conditioned on N; "
        "smooth pixel; mean error / RMS error / max |estimate|)",
        "",
    ]
    rows = []
    for label, entry in near["classes"].items():
        cells = [
            "-"
            if entry[m] is None
            else f"{fmt(entry[m]['mean_error'])} / {fmt(entry[m]['rms_error'])} / "
            f"{fmt(entry[m]['max_abs'])}" + ("" if entry[m]["finite"] else " NON-FINITE")
            for m in SPPP_NAMES
        ]
        rows.append([label, entry["pixels"], *cells])
    lines += table(["N", "pixels", *displayed(SPPP_NAMES)], rows)
    lines += [
        "",
        "### fvor with an empty filtered set (no W cell inside W')",
        "",
        *table(
            [
                "n",
                "eps",
                "valid pixels with N >= 1",
                "empty filter",
                "stats.empty_filtered",
                "frequency",
                "mean N when empty",
                "max abs(fvor - vor_sn) there",
                "RMS error: empty / kept",
            ],
            [
                [
                    r["n"],
                    fmt(r["eps"]),
                    r["valid_nonempty"],
                    r["empty_filtered"],
                    r["stats_empty_filtered"],
                    fmt(r["frequency"]),
                    fmt(r["mean_N_when_empty"]),
                    fmt(r["max_abs_fvor_minus_vor_sn"]),
                    f"{fmt(r['rms_error_empty'])} / {fmt(r['rms_error_kept'])}",
                ]
                for r in fvor_rows
            ],
        ),
    ]
    return lines


def rejection_markdown(rows: list[dict]) -> list[str]:
    worst = max(rows, key=lambda r: r["frequency"] / r["bound"])
    lines = [
        *table(
            [
                "n",
                "target bound",
                "eps",
                "n'",
                "rejected / pixels",
                "frequency",
                "95 % upper",
                "frequency / bound",
            ],
            [
                [
                    r["n"],
                    fmt(r["bound"]),
                    fmt(r["eps"]),
                    r["n_aux"],
                    f"{r['rejected']} / {r['pixels']}",
                    fmt(r["frequency"]),
                    fmt(r["upper_95"]),
                    fmt(r["frequency"] / r["bound"]),
                ]
                for r in rows
            ],
        ),
        "",
        f"Largest frequency / bound over all {len(rows)} configurations: "
        f"{fmt(worst['frequency'] / worst['bound'])} (n = {worst['n']}, bound "
        f"{fmt(worst['bound'])}). Configurations whose 95 % upper bound exceeds the "
        f"paper's bound: {sum(r['upper_95'] > r['bound'] for r in rows)} (with few "
        "pixels the upper bound can exceed a small bound without any rejection).",
    ]
    return lines


def storm_markdown(storm: dict) -> list[str]:
    header = [
        "driver",
        "seconds",
        "rounds",
        "redraws",
        "eps enlargements",
        "final eps",
        "exhausted",
        "Qhull calls",
        *[f"{display(m)} z" for m in SPPP_NAMES],
    ]
    rows = []
    reference = storm["reference"]
    if reference is not None:
        pixels = reference["mc"]["runs"]
        rows.append(
            [
                f"reference: paper's eps, no storm ({pixels} pixels)",
                "-",
                "-",
                "-",
                "-",
                fmt(storm["paper_eps"]),
                "-",
                "-",
                *[f"{reference[m]['z']:+.1f}" for m in SPPP_NAMES],
            ]
        )
    for label, run in storm["runs"].items():
        s = run["redraw"]
        rows.append(
            [
                label,
                f"{run['seconds']:.1f}",
                s["rounds"],
                s["redraws"],
                s["eps_enlargements"],
                fmt(s["final_eps"]),
                s["exhausted_pixels"],
                s["qhull_calls"],
                *[f"{run['summary']['holder_1'][m]['z']:+.1f}" for m in SPPP_NAMES],
            ]
        )
    lines = [
        f"n = {storm['n']}, eps = {storm['eps']:g} (the paper's eps is "
        f"{storm['paper_eps']:.4f}), {next(iter(storm['runs'].values()))['pixels']} "
        "pixels per driver setting; z = bias / SE of each estimator on holder_1 (exact "
        "1/16). Rounds and Qhull calls are per driver call (pixels are split into calls "
        "of about 200 000 points).",
        "",
        *table(header, rows),
        "",
        "With on_exhausted='raise' and the default driver: "
        + (
            f"`{storm['defaults_on_exhausted_raise']}`"
            if storm["defaults_on_exhausted_raise"]
            else "no error (the driver recovered: its first enlargement reaches the paper's eps)"
        ),
        "",
        "Bias on holder_1 of the pixels accepted at each eps (driver factor 1.5):",
        "",
    ]
    by_eps = storm["runs"][STORM_ATLAS_DRIVER]["by_accept_eps"]
    lines += table(
        ["eps at acceptance", "n'", "paper's bound there", "pixels", *displayed(SPPP_NAMES)],
        [
            [
                fmt(r["eps"]),
                r["n_aux"],
                fmt(r["bound"]),
                r["pixels"],
                *[fmt(r[m]) for m in SPPP_NAMES],
            ]
            for r in by_eps
        ],
    )
    return lines


def discontinuity_markdown(disc: dict) -> list[str]:
    lines = []
    for n, stats in disc.items():
        lines += [
            f"n = {n} (exact {EXACT[col('discontinuity')]:.6f}):",
            "",
            *table(
                [
                    "estimator",
                    "mean",
                    "std",
                    "IQR",
                    "MAD",
                    "median |error|",
                    "max |error|",
                    "5 largest estimates",
                ],
                [
                    [
                        display(name),
                        fmt(d["mean"]),
                        fmt(d["std"]),
                        fmt(d["iqr"]),
                        fmt(d["mad"]),
                        fmt(d["median_abs_error"]),
                        fmt(d["max_abs_error"]),
                        ", ".join(fmt(v) for v in d["largest"]),
                    ]
                    for name, d in stats.items()
                ],
            ),
            "",
        ]
    return lines


def firefly_markdown(fire: dict) -> list[str]:
    lines = []
    for n, stats in fire["by_n"].items():
        header = [
            "estimator",
            *[f"RMSE x{g}" for g in fire["gains"]],
            "finite",
            "n w mean",
            "n w rms",
            "n w max",
        ]
        rows = [
            [
                display(name),
                *[fmt(v) for v in d["rmse_by_gain"]],
                d["finite"],
                fmt(d["n_weight_mean"]),
                fmt(d["n_weight_rms"]),
                fmt(d["n_weight_max"]),
            ]
            for name, d in stats.items()
        ]
        lines += [f"n = {n}:", "", *table(header, rows), ""]
    return lines


def flat_markdown(flat: list[dict]) -> list[str]:
    names = [*ROW_NAMES, "baseline"]
    rows = [
        [
            r["n"],
            *[
                f"{fmt(r['estimators'][m]['std'])} / "
                f"{fmt(r['estimators'][m]['max_abs_error_N_ge_1'])}"
                for m in names
            ],
        ]
        for r in flat
    ]
    return table(["n", *displayed(ROW_NAMES), BASELINE], rows)


EXPLANATIONS = {
    "atlas": (
        "Each cell: verdict, the error ratio estimator / mc/independent (the mean of n uniform "
        "samples, the standard pixel estimator) and its 95 % bootstrap interval. better: the "
        "interval lies below 1; worse: above 1; same: it contains 1. Columns name each "
        "estimator with its samples: mc/sppp is mc over SPPP draws (sum / n under Poisson N), "
        "not the baseline. When mc/independent is exact (flat pixel) a "
        "cell compares the two errors directly. The discontinuity function has infinite "
        "variance, so its rows compare median absolute errors. mc, mc_n, vor, vor_sn and fvor "
        "run on SPPP draws (Poisson N, redrawn when rejected), cvor and pvor on the same kind "
        "of n uniform points as the baseline (paired resampling)."
    ),
    "small_n": (
        "Under Poisson N a pixel is empty with probability exp(-n) and every estimator returns 0 "
        "there. mc (sum / n) stays unbiased, and vor nearly (its truncated construction biases it"
        " by a few percent at n = 1: bench/vor_bias.py); the conditional forms (mc_n, vor_sn, "
        "fvor) lose the exp(-n) mass: their expectation is (1 - exp(-n)) I plus, for the ratio "
        "estimators, an O(1/n) term. cvor and pvor here use N = n uniform points and never see an"
        " empty pixel."
    ),
    "storm": (
        "The driver enlarges eps only after redraws_before_enlarge rounds and by a constant "
        "factor. A pixel is accepted at the first eps that happens to give it bounded cells, "
        "so in a storm most pixels are accepted at an eps where the paper's bound is far above "
        "alpha: those draws are conditioned on an event that is not rare, and the accepted "
        "estimates inherit its bias (all estimators, mc included, since they share the draw)."
    ),
    "fireflies": (
        "Every estimator is linear in the sample values, so a firefly of gain g at sample k "
        "moves the estimate by exactly (g - 1) f(x_k) w_k, w_k the sample's weight (1/n for "
        "mc, 1/N for mc_n, its cell area for vor, cell area over the summed areas for vor_sn "
        "and fvor (0 if fvor drops the cell), its clipped or torus cell area for cvor and "
        "pvor). The RMSE at large gains is therefore g f E[w^2]^(1/2); n w measures the "
        "weight against mc's 1/n."
    ),
    "flat": (
        "Cells: std over all pixels / max |estimate - 1| over pixels with N >= 1. Weights "
        "that sum to 1 (mc_n, vor_sn, fvor, cvor, pvor) are exact on f == 1 whenever N >= 1; "
        "mc (N / n) and the literal E_V (sum of the W nuclei's cell areas, which overhang W "
        "and miss the parts of W covered by strip cells) are not."
    ),
}


def build_report(results: dict, charts: dict, argv: list[str]) -> str:
    cfg = results["config"]
    lines = [
        "# Stability of the pixel estimators: the failure atlas",
        "",
        f"Command: `{' '.join(['python bench/stability_study.py', *argv])}` "
        f"(seed {cfg['seed']}, {'quick' if cfg['quick'] else 'full'} run, "
        f"{results['seconds']:.0f} s). Pixels per n: {cfg['runs']}. Measured in blocks of "
        f"{cfg['block_points']} points, {cfg['task_blocks']} per task, on: {cfg['executor']}.",
        "",
        "## Failure atlas",
        "",
        EXPLANATIONS["atlas"],
        "",
        *atlas_markdown(results["atlas"]),
        "",
        f"![atlas]({charts['atlas']})",
        "",
        report_caption(atlas_caption(results["config"])),
        "",
        f"## Where each estimator is worse than {BASELINE}",
        "",
        *worse_than_mc_markdown(results["atlas"]),
        "",
        "## Small n: empty and near-empty pixels",
        "",
        EXPLANATIONS["small_n"],
        "",
        *small_n_markdown(results["small_n"], results["near_empty"], results["fvor_empty"]),
        "",
        f"![small n]({charts['small_n']})",
        "",
        "## Rejection frequency against the paper's bound",
        "",
        "First-draw frequency of pixels with a W nucleus whose cell is unbounded, at the "
        "eps where the paper's bound 4 pi n^2 eps^2 exp(-pi n eps^2) equals each target.",
        "",
        *rejection_markdown(results["rejection"]),
        "",
        f"![rejection]({charts['rejection']})",
        "",
        "## Forced rejection storm",
        "",
        EXPLANATIONS["storm"],
        "",
        *storm_markdown(results["storm"]),
        "",
        f"![storm]({charts['storm']})",
        "",
        "## Discontinuity function (infinite variance)",
        "",
        *discontinuity_markdown(results["discontinuity"]),
        f"![discontinuity]({charts['discontinuity']})",
        "",
        "## Fireflies: one sample of a smooth pixel multiplied by a gain",
        "",
        EXPLANATIONS["fireflies"],
        "",
        *firefly_markdown(results["fireflies"]),
        f"![fireflies]({charts['fireflies']})",
        "",
        "## Flat pixel (f == 1)",
        "",
        EXPLANATIONS["flat"],
        "",
        *flat_markdown(results["flat"]),
        "",
        f"![flat]({charts['flat']})",
        "",
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# Main


@dataclass(frozen=True)
class Config:
    quick: bool
    seed: int
    ns: tuple[int, ...]
    runs: dict
    rejection_ns: tuple[int, ...]
    rejection_pixels: int
    fvor_ns: tuple[int, ...]
    fvor_pixels: int
    storm_pixels: int
    near_empty_n: int = 2
    discontinuity_ns: tuple[int, ...] = (16, 64, 256)
    firefly_ns: tuple[int, ...] = (16, 64, 256)

    def rejection_pixels_for(self, n: int, alpha: float) -> int:
        """Fewer pixels at large n (cost ~ n); four times more at the smallest bound."""
        pixels = self.rejection_pixels * min(1.0, 16.0 / n) ** 0.5
        return int(pixels * (4 if alpha == min(REJECTION_BOUNDS) else 1))


def make_config(quick: bool, seed: int) -> Config:
    if quick:
        ns = (1, 2, 4, 16, 64)
        return Config(
            True,
            seed,
            ns,
            {n: 300 if n <= 16 else 150 for n in ns},
            (1, 4, 16),
            300,
            (1, 4),
            400,
            40,
            discontinuity_ns=(16, 64),
            firefly_ns=(16, 64),
        )
    ns = (1, 2, 3, 4, 6, 8, 12, 16, 32, 64, 256)
    runs = {n: 6000 if n <= 16 else 4000 if n <= 32 else 3000 if n <= 64 else 1500 for n in ns}
    return Config(
        False,
        seed,
        ns,
        runs,
        (*range(1, 17), 32, 64, 256),
        3000,
        (1, 2, 3, 4, 6, 8, 12, 16, 64),
        4000,
        800,
    )


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smoke run (well under a minute)")
    parser.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).parent / "results" / "stability",
        help="output folder (default bench/results/stability)",
    )
    parser.add_argument(
        "--seed", type=int, default=2026, help="seed of every random stream (default 2026)"
    )
    parser.add_argument(
        "--task-blocks",
        type=positive_int,
        default=1,
        help="blocks per task (default 1; the numbers do not depend on it)",
    )
    add_executor_options(parser)
    return parser.parse_args(argv)


def measure(cfg: Config, executor=None, task_blocks: int = 1) -> tuple[dict, dict[int, Runs]]:
    """The measurements: the heavy sections (the runs per n, fvor's empty filter, the rejection
    frequencies) as blocks on the executor, all in one map so that it balances them; the
    storm (a few seconds) here."""
    seed = cfg.seed
    plan: dict[tuple, list[Block]] = {}
    for n in cfg.ns:
        plan["sppp", n] = sppp_blocks(n, cfg.runs[n], (seed, STREAM_SPPP, n))
        plan["uniform", n] = blocks_of("uniform", n, cfg.runs[n], (seed, STREAM_UNIFORM, n), n)
    for n in cfg.fvor_ns:
        plan["fvor", n] = [Block("fvor", n, 0, cfg.fvor_pixels, (seed, STREAM_FVOR, n))]
    for n in cfg.rejection_ns:
        for index, alpha in enumerate(REJECTION_BOUNDS):
            pixels = cfg.rejection_pixels_for(n, alpha)
            plan["rejection", n, index] = rejection_blocks(n, index, pixels, seed)
    start = time.perf_counter()
    results = run_blocks(
        [block for blocks in plan.values() for block in blocks], executor, task_blocks
    )
    done, first = {}, 0
    for key, blocks in plan.items():
        done[key] = results[first : first + len(blocks)]
        first += len(blocks)
    tasks = math.ceil(len(results) / task_blocks)
    print(
        f"{len(results)} blocks in {tasks} tasks: {time.perf_counter() - start:.1f} s",
        flush=True,
    )
    all_runs = {}
    for n in cfg.ns:
        all_runs[n] = runs_of(n, done["sppp", n], done["uniform", n])
        print(
            f"n = {n}: {cfg.runs[n]} pixels, {all_runs[n].seconds:.1f} s, redraw "
            f"{all_runs[n].redraw}",
            flush=True,
        )
    fvor_rows = [done["fvor", n][0][0] for n in cfg.fvor_ns]
    rejection = [
        rejection_row(n, alpha, cfg.rejection_pixels_for(n, alpha), done["rejection", n, index])
        for n in cfg.rejection_ns
        for index, alpha in enumerate(REJECTION_BOUNDS)
    ]
    start = time.perf_counter()
    storm = storm_section(cfg.storm_pixels, seed)
    print(f"storm: {time.perf_counter() - start:.1f} s", flush=True)
    return {"fvor_empty": fvor_rows, "rejection": rejection, "storm": storm}, all_runs


def analyse(cfg: Config, measured: dict, all_runs: dict[int, Runs], rng) -> dict:
    return {
        "atlas": build_atlas(all_runs, measured["storm"], rng),
        "small_n": small_n_section(all_runs),
        "near_empty": near_empty_section(all_runs[cfg.near_empty_n]),
        "fvor_empty": measured["fvor_empty"],
        "rejection": measured["rejection"],
        "storm": {**measured["storm"], "reference": storm_reference(all_runs)},
        "discontinuity": discontinuity_section(all_runs, cfg.discontinuity_ns),
        "fireflies": firefly_section(all_runs, cfg.firefly_ns),
        "flat": flat_section(all_runs),
        "redraw_by_n": {n: r.redraw for n, r in all_runs.items()},
        "seconds_by_n": {n: r.seconds for n, r in all_runs.items()},
    }


def plot_all(results: dict, all_runs: dict[int, Runs], out: Path) -> dict:
    return {
        "atlas": plot_atlas(results["atlas"], out, results["config"]),
        "small_n": plot_small_n(results["small_n"], out),
        "rejection": plot_rejection(results["rejection"], out),
        "storm": plot_storm(results["storm"], out),
        "discontinuity": plot_discontinuity(results["discontinuity"], all_runs, out),
        "fireflies": plot_fireflies(results["fireflies"], out),
        "flat": plot_flat(results["flat"], out),
    }


def jsonable(obj):
    """Plain JSON types: arrays to lists, numpy scalars to Python, dict keys to str."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    return obj


def write_outputs(results: dict, all_runs: dict[int, Runs], out: Path, argv) -> None:
    storm_raw = {label: run.pop("holder_1") for label, run in results["storm"]["runs"].items()}
    np.savez_compressed(
        out / "estimates.npz",
        columns=np.array(COLUMNS),
        **{f"n{n}_{name}": e for n, r in all_runs.items() for name, e in r.estimates.items()},
        **{f"n{n}_counts": r.counts for n, r in all_runs.items()},
        **{
            f"storm_{i}_{name}": e
            for i, raw in enumerate(storm_raw.values())
            for name, e in raw.items()
        },
    )
    (out / "results.json").write_text(json.dumps(jsonable(results), indent=1))
    charts = results.pop("charts")
    (out / "report.md").write_text(build_report(results, charts, argv))


def print_summary(results: dict) -> None:
    print(
        "\n".join(
            [
                "",
                f"Failure atlas (error ratio estimator / {BASELINE}):",
                *atlas_markdown(results["atlas"]),
                "",
                f"Worse than {BASELINE}:",
                *worse_than_mc_markdown(results["atlas"]),
            ]
        )
    )


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv)
    cfg = make_config(args.quick, args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    # The bootstrap's stream; the measurements have their own (see Blocks)
    rng = np.random.default_rng(args.seed)
    start = time.perf_counter()
    machine_before = machine()
    with executor_from_args(args) as executor:
        measured, all_runs = measure(cfg, executor, args.task_blocks)
    results = analyse(cfg, measured, all_runs, rng)
    results["config"] = {
        "quick": cfg.quick,
        "seed": cfg.seed,
        "runs": cfg.runs,
        "rejection_ns": cfg.rejection_ns,
        "fvor_ns": cfg.fvor_ns,
        "storm_pixels": cfg.storm_pixels,
        "block_points": BLOCK_POINTS,
        "task_blocks": args.task_blocks,
        "executor": executor_label(args),
        "columns": COLUMNS,
        "exact": dict(zip(COLUMNS, EXACT.tolist(), strict=True)),
        "baseline": BASELINE,
    }
    results["charts"] = plot_all(results, all_runs, args.out)
    results["seconds"] = time.perf_counter() - start
    # The machine is shared: its load before and after the measurements
    results["machine_before"] = machine_before
    results["machine_after"] = machine()
    print_summary(results)
    write_outputs(results, all_runs, args.out, argv)
    print(
        f"wrote {args.out}/report.md, results.json, estimates.npz and PNG charts "
        f"({results['seconds']:.0f} s)"
    )


if __name__ == "__main__":
    main()
