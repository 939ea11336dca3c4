"""Whole-image error of every estimator on the authors' Cornell box: the paper's Figure 7.

    python bench/image_study.py [--quick] [--size N] [--spp 256] [--seeds 3] [--reference-spp 4096]
        [--workers N | --scheduler ADDRESS]

A reference (bench/common.py: the mean of 4 sobol mc renders of reference-spp / 4 samples
each, cached as EXR under bench/results/references/ with its measured noise), then --seeds
renders (seeds --seed, --seed + 1, ...) per (estimator, sampler) pair at --spp through the full
pipeline (clrender.pipeline), and for each: whole-image errors against the reference
(bench/common.image_errors: MSE = mean over pixels and RGB channels of the squared difference
of linear radiance; also less the reference's own noise, clamped to [0, 1], and on sRGB-encoded
values), an error map (|render - reference|, mean of RGB, one colour scale for all maps, of the
first seed) and the render itself.
Per pair: each error's mean over the seeds, its per-seed values and standard error; mse.png
shows the MSE per pair (mean +- standard error, each seed a dot). The paper's MSE at 256 spp
(0.030 for MC, 0.015 for its "vor", which is self-normalised: our vor_sn) is printed alongside,
labelled with its spp; the ratios in the report carry 95 % bootstrap intervals over the seeds.

Resolution: 256 x 256 when RenderSettings has the device Voronoi backend (voronoi_backend,
the default there), else 128 x 128 (host Qhull cells take minutes per 256 x 256 render on two
cores).
Where: each (pair, seed) render is one task (bench/common.py render_task: a whole render,
after an untimed warm-up of its pair in the process that renders it), in this process by
default, or on a Dask cluster with --workers N / --scheduler ADDRESS. Images and errors are
bit-identical wherever they run; the times are taken on the worker that rendered (wall, device,
host and CPU seconds of that render in that worker process). On a cluster the workers render
different pairs at once and share the cores, so wall times there include waiting for the other
workers: compare CPU times across runs, and wall times only within one run. A reference not
yet cached is split over the cluster by pixel ranges (clrender.cluster.render_on, bit-identical
to the local one, so the cached file serves both). results.json and the report say where the
renders ran.

Outputs (default bench/results/image_study/): results.json, report.md, mse.png, renders.png,
error_maps.png, error_<estimator>_<sampler>.png, render_<estimator>_<sampler>.png and .exr.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from bootstrap import ratio_interval  # noqa: E402
from common import (  # noqa: E402
    MAX_DEPTH,
    PAPER_MSE,
    REFERENCE_PARTS,
    REFERENCE_SAMPLER,
    RENDER_PAIRS,
    RESULTS,
    RenderTask,
    add_executor_options,
    command_line,
    default_backend,
    executor_from_args,
    executor_record,
    has_backend_setting,
    image_errors,
    machine,
    markdown_table,
    pair_label,
    process_runtime,
    reference,
    render_tasks,
    write_json,
)
from figures import (  # noqa: E402
    caption,
    draw_caption,
    legend_beside,
    report_caption,
    save_figure,
    spread,
)

from clrender.imageio import srgb8, write_exr, write_png  # noqa: E402

ERROR_COLOURMAP = "inferno"
# The error maps share one scale: this percentile of mc/independent's error map.
ERROR_SCALE_PERCENTILE = 99.0


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: 32 x 32, 16 spp, 2 seeds, reference 64 spp",
    )
    parser.add_argument("--scene", default="cornell-box")
    parser.add_argument(
        "--size",
        type=int,
        default=None,
        help="width = height (default 256 with the device backend, else 128)",
    )
    parser.add_argument("--spp", type=int, default=None, help="default 256")
    parser.add_argument("--reference-spp", type=int, default=None, help="default 4096")
    parser.add_argument("--seed", type=int, default=1, help="the first seed")
    parser.add_argument("--seeds", type=int, default=None, help="renders per pair (default 3)")
    parser.add_argument(
        "--backend",
        default=default_backend(),
        help="RenderSettings.voronoi_backend: device (default) or qhull",
    )
    parser.add_argument("--out", type=Path, default=RESULTS / "image_study")
    add_executor_options(parser)
    args = parser.parse_args(argv)
    args.size = args.size or (32 if args.quick else 256 if has_backend_setting() else 128)
    args.spp = args.spp or (16 if args.quick else 256)
    args.reference_spp = args.reference_spp or (64 if args.quick else 4096)
    args.seeds = args.seeds or (2 if args.quick else 3)
    return args


ERRORS = (
    "mse",
    "ref_noise",
    "mse_minus_ref_noise",
    "mse_clamped",
    "mse_srgb",
    "top_share",
    "bright_share",
    "bright_fraction",
)
TIMES = ("wall_s", "device_s", "host_s", "cpu_s")
PAPER_SPP = 256  # the spp of the paper's Figure 7 (PAPER_MSE)
BOOTSTRAP = 2000  # resamples of a ratio's interval


def seeds(args) -> list[int]:
    return [args.seed + k for k in range(args.seeds)]


def run_pairs(executor, args, ref, ref_var) -> tuple[list[dict], dict]:
    """(one row per render, {pair: image of the first seed}): every (seed, pair) render a task
    on the executor."""
    size = (args.size, args.size)
    tasks = [
        RenderTask(args.scene, size, (estimator,), sampler, args.spp, seed, args.backend)
        for seed in seeds(args)
        for estimator, sampler in RENDER_PAIRS
    ]
    rows, images = [], {}
    for task, (rendered, row) in zip(tasks, render_tasks(executor, tasks), strict=True):
        image = rendered[task.estimators[0]].astype(np.float64)
        row.update(image_errors(image, ref, ref_var))
        rows.append(row)
        images.setdefault(pair_label(row["estimator"], row["sampler"]), image)
        print_row(row)
    return rows, images


def print_row(row: dict) -> None:
    print(
        f"seed {row['seed']} {pair_label(row['estimator'], row['sampler']):18s} MSE "
        f"{row['mse']:.5f} (less ref noise "
        f"{row['mse_minus_ref_noise']:.5f}, clamped {row['mse_clamped']:.5f}, sRGB "
        f"{row['mse_srgb']:.5f}, top 0.1 % share {row['top_share']:.2f})  wall "
        f"{row['wall_s']:.1f} s (device {row['device_s']:.1f}, host {row['host_s']:.1f}), CPU "
        f"{row['cpu_s']:.1f} s on {row['worker']}",
        flush=True,
    )


def summarise(renders: list[dict]) -> list[dict]:
    """One row per pair, in RENDER_PAIRS order: each error and time's mean over the seeds, and
    for the MSE its per-seed values and standard error (mse_per_seed, mse_se)."""
    rows = []
    for estimator, sampler in RENDER_PAIRS:
        mine = [r for r in renders if (r["estimator"], r["sampler"]) == (estimator, sampler)]
        mse = spread([r["mse"] for r in mine])
        row = {
            "estimator": estimator,
            "sampler": sampler,
            "cells": mine[0]["cells"],
            "seeds": [r["seed"] for r in mine],
            "mse_per_seed": mse["values"],
            "mse_se": mse["se"],
            "mse_minus_ref_noise_per_seed": [r["mse_minus_ref_noise"] for r in mine],
        }
        for key in ERRORS + TIMES:
            row[key] = statistics.fmean(r[key] for r in mine)
        rows.append(row)
    return rows


def mse_ratio(a: dict, b: dict, key: str, rng) -> tuple[float, float | None, float | None]:
    """mean key(a) / mean key(b) over the seeds and its 95 % percentile bootstrap interval
    (independent renders, each pair's seeds resampled on their own; none under two seeds)."""
    x = np.array(a.get(f"{key}_per_seed", [a[key]]))
    y = np.array(b.get(f"{key}_per_seed", [b[key]]))
    if min(len(x), len(y)) < 2:
        return a[key] / b[key], None, None
    return ratio_interval(x, y, np.mean, rng, paired=False, resamples=BOOTSTRAP)


def ratio_text(ratio: tuple) -> str:
    value, lo, hi = ratio
    return f"{value:.2f}" + ("" if lo is None else f" [{lo:.2f}, {hi:.2f}]")


def error_map(image: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return np.abs(image - ref).mean(axis=-1)


def save_images(images: dict, ref: np.ndarray, out: Path) -> float:
    """Per-pair render and error-map PNGs (one colour scale); returns the scale's top."""
    vmax = float(np.percentile(error_map(images["mc/independent"], ref), ERROR_SCALE_PERCENTILE))
    write_png(out / "reference.png", ref)
    for label, image in images.items():
        name = label.replace("/", "_")
        write_png(out / f"render_{name}.png", image)
        write_exr(out / f"render_{name}.exr", image)
        plt.imsave(
            out / f"error_{name}.png",
            error_map(image, ref),
            cmap=ERROR_COLOURMAP,
            vmin=0.0,
            vmax=vmax,
        )
    return vmax


def plot_grids(
    images: dict,
    ref: np.ndarray,
    ref_var: np.ndarray,
    rows: list[dict],
    vmax: float,
    args,
    device: str,
    out: Path,
) -> None:
    mse = {
        pair_label(r["estimator"], r["sampler"]): f"{r['mse']:.4f} +- {r['mse_se']:.1g}"
        for r in rows
    }
    cols = 4
    panels = len(images) + 1
    nrows = -(-panels // cols)
    for kind in ("renders", "error_maps"):
        fig, axes = plt.subplots(
            nrows,
            cols,
            figsize=(3.2 * cols, 3.3 * nrows + 0.8),
            squeeze=False,
            layout="constrained",
        )
        for ax in axes.flat:  # no axes drawn, and no ticks for the layout to measure
            ax.set_axis_off()
            ax.set_xticks([])
            ax.set_yticks([])
        # The reference itself, and on the error maps its own noise (std of the mean).
        noise = np.sqrt(ref_var).mean(axis=-1)
        axes.flat[0].imshow(
            srgb8(ref) if kind == "renders" else noise, cmap=ERROR_COLOURMAP, vmin=0, vmax=vmax
        )
        axes.flat[0].set_title(
            f"reference ({args.reference_spp} spp)"
            if kind == "renders"
            else "reference noise (std)",
            fontsize=9,
        )
        for ax, (label, image) in zip(axes.flat[1:], images.items(), strict=False):
            shown = srgb8(image) if kind == "renders" else error_map(image, ref)
            handle = ax.imshow(shown, cmap=ERROR_COLOURMAP, vmin=0, vmax=vmax)
            ax.set_title(f"{label}\nMSE {mse[label]}", fontsize=9)
        if kind == "error_maps":
            fig.colorbar(
                handle,
                ax=list(axes.flat),
                shrink=0.6,
                label="|render - reference| (linear radiance, mean of RGB)",
            )
        draw_caption(fig, figure_caption(kind, args, device), width=110)
        save_figure(fig, out / f"{kind}.png", dpi=90)
        plt.close(fig)


def figure_caption(kind: str, args, device: str) -> str:
    """Every parameter of the study's figures: "mse", "renders" or "error_maps"."""
    what = {
        "mse": "Whole-image MSE of every estimator/sampler pair (the paper's Figure 7)",
        "renders": "Renders of every pair, first seed, beside the reference",
        "error_maps": "Error maps |render - reference| of every pair, first seed, and the "
        "reference's own noise, one colour scale",
    }[kind]
    return caption(
        what,
        {
            "scene": args.scene,
            "resolution": f"{args.size} x {args.size}",
            "spp": args.spp,
            "seeds": f"{args.seeds} per pair ({', '.join(str(s) for s in seeds(args))})"
            if kind == "mse"
            else f"seed {args.seed} shown, of {args.seeds}",
            "points": "mean MSE over the seeds, linear radiance, against the reference; "
            "dots: each seed"
            if kind == "mse"
            else "titles: mean MSE +- standard error over the seeds",
            "error bars": "+- 1 standard error of the mean over the seeds"
            if kind == "mse"
            else None,
            "labels": "estimator/sampler (mc/independent: plain Monte Carlo over uniform "
            "samples, the paper's MC baseline)",
            "reference": f"mc/{REFERENCE_SAMPLER}, {args.reference_spp} spp in "
            f"{REFERENCE_PARTS} parts",
            "max depth": MAX_DEPTH,
            "device": device,
            "Voronoi cells": f"{args.backend} where the estimator has them there, else host "
            "Qhull (per pair in the report's table)"
            if args.backend
            else "host Qhull",
        },
    )


def plot_mse(rows: list[dict], args, device: str, out: Path) -> None:
    """MSE per pair: bars of the mean over the seeds, standard-error bars, a dot per seed."""
    labels = [pair_label(r["estimator"], r["sampler"]) for r in rows]
    fig, ax = plt.subplots(figsize=(9, 0.35 * len(rows) + 2.2), layout="constrained")
    y = np.arange(len(rows))
    se = [0.0 if np.isnan(r["mse_se"]) else r["mse_se"] for r in rows]
    ax.barh(y, [r["mse"] for r in rows], xerr=se, capsize=3, color="0.8", ecolor="C0", label="mean")
    for i, r in enumerate(rows):
        ax.plot(r["mse_per_seed"], [i] * len(r["mse_per_seed"]), "k.", ms=4)
    ax.plot([], [], "k.", ms=4, label="one seed")
    ax.set_yticks(y, labels)
    ax.invert_yaxis()
    ax.set(xlabel="MSE (linear radiance, mean of RGB)", title=f"{args.scene}: MSE per pair")
    legend_beside(fig, [ax])
    draw_caption(fig, figure_caption("mse", args, device), width=120)
    save_figure(fig, out / "mse.png", dpi=90)
    plt.close(fig)


def explanation(rows: list[dict], ref_info: dict, args) -> list[str]:
    by = {pair_label(r["estimator"], r["sampler"]): r for r in rows}
    mc, sn, vor = by["mc/independent"], by["vor_sn/sppp"], by["vor/sppp"]
    noise = mc["ref_noise"]
    rng = np.random.default_rng(0)
    paper = (
        "the paper's spp"
        if args.spp == PAPER_SPP
        else f"**this run is at {args.spp} spp, the paper's figures at {PAPER_SPP}**"
    )
    return [
        f"## Beside the paper (at {PAPER_SPP} spp: MSE {PAPER_MSE['mc']} MC, "
        f"{PAPER_MSE['vor']} vor, ratio {PAPER_MSE['mc'] / PAPER_MSE['vor']:.1f}; {paper})",
        "",
        f"Ratios of mean errors over {args.seeds} seeds, with 95 % bootstrap intervals over the "
        "seeds (bench/bootstrap.py):",
        "",
        "- Ratio mc/independent : vor_sn/sppp = "
        f"{ratio_text(mse_ratio(mc, sn, 'mse', rng))} (linear MSE), "
        f"{ratio_text(mse_ratio(mc, sn, 'mse_minus_ref_noise', rng))} after removing the "
        f"reference noise, {mc['mse_srgb'] / sn['mse_srgb']:.2f} on sRGB values; mc/independent : "
        f"vor/sppp (literal E_V) = {ratio_text(mse_ratio(mc, vor, 'mse', rng))}. The paper's "
        "'vor' is what the authors' renderer computes, i.e. the self-normalised vor_sn (NOTES.md "
        "section 1).",
        f"- Reference noise: the reference ({ref_info['spp']} spp as {ref_info['parts']} "
        f"{ref_info['sampler']} parts) has a measured variance of {noise:.2e} per pixel channel, "
        f"{100 * noise / sn['mse']:.1f} % of vor_sn's MSE and {100 * noise / mc['mse']:.1f} % of "
        "mc's; 'MSE - ref noise' removes it (the render and reference are independent).",
        f"- Where the error sits: the pixels brighter than display white (reference RGB mean "
        f"> 1: the light and the pixels its outline crosses, {100 * mc['bright_fraction']:.1f} "
        f"% of the image) hold {100 * mc['bright_share']:.0f} % of mc/independent's squared error "
        f"and {100 * sn['bright_share']:.0f} % of vor_sn's; the worst 0.1 % of pixel channels "
        f"hold {100 * mc['top_share']:.0f} % and {100 * sn['top_share']:.0f} %. So the linear "
        "MSE mostly measures the light's outline, where Voronoi weighting helps most (see "
        "bench/pixel_study.py). Clamped to [0, 1] (the display range, which removes that "
        "outline), mc/independent : vor_sn = "
        f"{mc['mse_clamped'] / sn['mse_clamped']:.2f}: on noise-"
        "dominated pixels the random cell areas add variance (a Poisson-Voronoi cell's area "
        "has a variance of about 0.28 / n^2, so sum f v has about 1.28x the variance of the "
        "plain mean when the values are uncorrelated noise). The paper does not say which "
        "values its MSE was computed on.",
        f"- Absolute levels: our linear MSE of mc is {mc['mse'] / PAPER_MSE['mc']:.2f}x the "
        f"paper's at {args.size} x {args.size} (the paper's resolution is not stated). The "
        "authors' renderer differs from ours (NOTES.md section 4: exactly n points, a corner-"
        "heavy strip, MIS weighting the whole recursive radiance, the glass ball listed as a "
        "light), so its images and errors are not expected to match ours in level; the ratio "
        "between estimators is the comparable figure.",
        "",
    ]


def report(results: dict, args, argv) -> str:
    rows = results["rows"]
    header = [
        "pair",
        "cells",
        "MSE (mean over seeds)",
        "+- SE",
        "MSE - ref noise",
        "MSE clamped",
        "MSE sRGB",
        "top 0.1 % share",
        "bright share",
        f"paper MSE ({PAPER_SPP} spp)",
        "wall s",
        "device s",
        "host s",
        "CPU s",
    ]
    paper = {"mc/independent": PAPER_MSE["mc"], "vor_sn/sppp": PAPER_MSE["vor"]}
    table = [
        [
            pair_label(r["estimator"], r["sampler"]),
            r["cells"],
            r["mse"],
            r["mse_se"],
            r["mse_minus_ref_noise"],
            r["mse_clamped"],
            r["mse_srgb"],
            r["top_share"],
            r["bright_share"],
            paper.get(pair_label(r["estimator"], r["sampler"]), ""),
            r["wall_s"],
            r["device_s"],
            r["host_s"],
            r["cpu_s"],
        ]
        for r in rows
    ]
    ref = results["reference"]
    origin = "cached" if ref["cached"] else "rendered"
    return "\n".join(
        [
            "# Image study (paper Figure 7)",
            "",
            f"Command: `{command_line('image_study.py', argv)}`",
            "",
            f"{args.scene}, {args.size} x {args.size}, {args.spp} spp, {args.seeds} seeds per pair "
            f"({', '.join(str(s) for s in seeds(args))}; every error is the mean over them), max "
            f"depth {MAX_DEPTH}, device {results['device']}, Voronoi cells per pair in the table "
            "(device kernel or host Qhull). Reference: "
            f"mean of {ref['parts']} {ref['sampler']} mc renders, {ref['spp']} spp in all "
            f"({origin}: "
            f"{Path(ref['path']).name}). "
            "MSE = mean over pixels and RGB channels of (render - reference)^2 in linear "
            "radiance; SE: its standard error over the seeds. The paper's column is its Figure 7 "
            f"at {PAPER_SPP} spp"
            + ("." if args.spp == PAPER_SPP else f", not this run's {args.spp} spp.")
            + f" Renders ran in {results['executor']['where']}, each timed "
            f"{results['executor']['timed']}; times are means over the seeds."
            + f" Machine: {results['machine']['uptime']}",
            "",
            markdown_table(header, table),
            "",
            "![MSE per pair](mse.png)",
            "",
            report_caption(figure_caption("mse", args, results["device"])),
            "",
            *explanation(rows, ref, args),
            "![renders](renders.png)",
            "",
            report_caption(figure_caption("renders", args, results["device"])),
            "",
            "![error maps](error_maps.png)",
            "",
            report_caption(figure_caption("error_maps", args, results["device"])),
            "",
        ]
    )


def main(argv=None) -> None:
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    with executor_from_args(args) as executor:
        run(args, executor, argv)


def run(args, executor, argv) -> None:
    runtime = process_runtime()
    start = time.perf_counter()
    size = (args.size, args.size)
    ref, ref_var, ref_info = reference(
        runtime, args.scene, size, args.reference_spp, executor=executor
    )
    renders, images = run_pairs(executor, args, ref, ref_var)
    rows = summarise(renders)
    device = runtime.describe()
    vmax = save_images(images, ref, args.out)
    plot_grids(images, ref, ref_var, rows, vmax, args, device, args.out)
    plot_mse(rows, args, device, args.out)
    results = {
        "settings": {k: str(v) for k, v in vars(args).items()},
        "device": device,
        "executor": executor_record(executor, args),
        "reference": ref_info,
        "rows": rows,
        "renders": renders,
        "paper_mse": PAPER_MSE,
        "error_scale_max": vmax,
        "machine": machine(),
        "seconds": time.perf_counter() - start,
    }
    write_json(args.out / "results.json", results)
    (args.out / "report.md").write_text(report(results, args, argv) + "\n")
    print(
        f"paper at {PAPER_SPP} spp: MSE mc 0.030, vor 0.015 (ratio 2.0); done in "
        f"{results['seconds']:.0f} s; wrote {args.out}/"
    )


if __name__ == "__main__":
    main()
