"""Accuracy against speed: whole-image MSE against wall time for every estimator, on both
shipped Cornell boxes, at several spp; and the Voronoi-over-mc wall-time ratio.

    python bench/efficiency_study.py [--quick] [--size N] [--spp 16 64 256]
    python bench/efficiency_study.py --perf-ratio [--perf-estimator NAME] [--repeats 3]

Default mode: for each scene (cornell-box, cornell-box-glossy) a cached reference
(bench/common.py: 4 stratified mc parts, 4096 spp in all, noise measured), then one render per
(estimator, sampler) pair and spp through the full pipeline, and the image MSE (mean over
pixels and RGB channels, linear radiance) against the render's wall time. One chart per scene
(efficiency_<scene>.png) and both side by side (efficiency.png); results.json and report.md.
Wall times come from one render each on a shared machine: the load average is recorded.

--perf-ratio: the issue's performance figure. The authors' Cornell box at 256 x 256 and 256
spp: mc over uniform samples against the best Voronoi estimator (by default the one of vor,
vor_sn, fvor -- the SPPP-cell estimators the device backend computes -- with the lowest MSE at
the highest spp of a previous default-mode run on cornell-box, else vor_sn), alternated after
a warm-up, --repeats times each; medians of wall, device and host seconds and the ratio of
median wall times (target <= 1.5). Output: perf_ratio.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

# As python -m clrender does: one BLAS thread, so idle OpenBLAS workers do not spin on the
# cores the OpenCL device renders on (before NumPy loads).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import (  # noqa: E402
    RENDER_PAIRS,
    RESULTS,
    command_line,
    default_backend,
    has_backend_setting,
    image_errors,
    machine,
    make_source,
    markdown_table,
    pair_label,
    reference,
    timed_render,
    write_json,
)

from clrender.estimators import ESTIMATORS, estimator_info  # noqa: E402
from clrender.runtime import create_runtime  # noqa: E402

SCENES = ["cornell-box", "cornell-box-glossy"]
DEFAULT_PERF_ESTIMATOR = "vor_sn"
# The perf-ratio candidates: the estimators of SPPP cells (W + auxiliary nuclei), the ones the
# device cell-area backend computes (vor, vor_sn, fvor); cvor is left out as biased (the paper
# drops it too).
PERF_CANDIDATES = tuple(name for name, entry in ESTIMATORS.items() if entry.device_sums)
MARKERS = "osD^vP*Xh<>"


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: 24 x 24, spp 4 16, reference 64 (perf: 32 x 32)",
    )
    parser.add_argument("--scenes", nargs="+", default=SCENES)
    parser.add_argument(
        "--size",
        type=int,
        default=None,
        help="width = height (default 64, 128 with the device backend; --perf-ratio: 256)",
    )
    parser.add_argument(
        "--spp",
        type=int,
        nargs="+",
        default=None,
        help="perfect squares (stratified); default 16 64 256",
    )
    parser.add_argument("--reference-spp", type=int, default=None, help="default 4096")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--backend",
        default=default_backend(),
        help="RenderSettings.voronoi_backend: device (default) or qhull",
    )
    parser.add_argument(
        "--perf-ratio",
        action="store_true",
        help="only mc vs the best Voronoi estimator at 256 spp, 256 x 256",
    )
    parser.add_argument("--perf-estimator", default=None)
    parser.add_argument("--repeats", type=int, default=None, help="perf-ratio repeats (3)")
    parser.add_argument("--out", type=Path, default=RESULTS / "efficiency_study")
    args = parser.parse_args(argv)
    big = 128 if has_backend_setting() else 64
    if args.perf_ratio:
        args.size = args.size or (32 if args.quick else 256)
        args.spp = args.spp or ([16] if args.quick else [256])
        args.repeats = args.repeats or (1 if args.quick else 3)
    args.size = args.size or (24 if args.quick else big)
    args.spp = args.spp or ([4, 16] if args.quick else [16, 64, 256])
    args.reference_spp = args.reference_spp or (64 if args.quick else 4096)
    return args


# ---------------------------------------------------------------------------------------------
# MSE against time


def study_scene(runtime, scene: str, args) -> dict:
    ref, ref_var, ref_info = reference(runtime, scene, (args.size, args.size), args.reference_spp)
    source = make_source(runtime, scene, args.size, args.size)
    timed_render(runtime, source, "mc", "independent", 1, 0)  # warm-up: kernel builds
    rows = []
    for spp in args.spp:
        for estimator, sampler in RENDER_PAIRS:
            image, row = timed_render(
                runtime, source, estimator, sampler, spp, args.seed, args.backend
            )
            row.update(image_errors(image, ref, ref_var))
            rows.append(row)
            print(
                f"{scene} {spp:4d} spp {pair_label(estimator, sampler):18s} MSE "
                f"{row['mse']:.5f}  wall {row['wall_s']:6.2f} s (device {row['device_s']:.2f},"
                f" host {row['host_s']:.2f})  load {row['load_1min']:.1f}",
                flush=True,
            )
    return {"reference": ref_info, "rows": rows}


def plot_scene(ax, scene: str, entry: dict) -> None:
    for i, (estimator, sampler) in enumerate(RENDER_PAIRS):
        pts = sorted(
            (r["spp"], r["wall_s"], r["mse"])
            for r in entry["rows"]
            if (r["estimator"], r["sampler"]) == (estimator, sampler)
        )
        style = "--" if ESTIMATORS[estimator].cells == "none" else "-"  # mc, mc_n
        ax.loglog(
            [p[1] for p in pts],
            [p[2] for p in pts],
            style,
            marker=MARKERS[i % 11],
            ms=4,
            color=f"C{i % 10}",
            label=pair_label(estimator, sampler),
        )
        spp, wall, mse = pts[-1]
        ax.annotate(f"{spp}", (wall, mse), fontsize=6, xytext=(2, 2), textcoords="offset points")
    noise = entry["rows"][0]["ref_noise"]
    ax.axhline(noise, color="k", lw=0.7, ls=":", label="reference noise")
    ax.set(
        xlabel="wall time per render (s)",
        ylabel="image MSE (linear, mean of RGB)",
        title=f"{scene}: error against time",
    )
    ax.legend(fontsize=6, ncol=2)


def plot_all(results: dict, args) -> None:
    scenes = results["scenes"]
    for scene, entry in scenes.items():
        fig, ax = plt.subplots(figsize=(7, 5))
        plot_scene(ax, scene, entry)
        ax.set_title(f"{scene} {args.size}x{args.size}, spp {args.spp}: MSE against wall time")
        fig.tight_layout()
        fig.savefig(args.out / f"efficiency_{scene}.png", dpi=100)
        plt.close(fig)
    fig, axes = plt.subplots(1, len(scenes), figsize=(7 * len(scenes), 5), squeeze=False)
    for ax, (scene, entry) in zip(axes.flat, scenes.items(), strict=True):
        plot_scene(ax, scene, entry)
    fig.suptitle(
        f"Image MSE against wall time, {args.size}x{args.size}, spp {args.spp} "
        "(labels: highest spp)"
    )
    fig.tight_layout()
    fig.savefig(args.out / "efficiency.png", dpi=100)
    plt.close(fig)


def report(results: dict, args, argv) -> str:
    lines = [
        "# Efficiency study: image MSE against wall time",
        "",
        f"Command: `{command_line('efficiency_study.py', argv)}`",
        "",
        f"{args.size} x {args.size}, spp {args.spp}, seed {args.seed}, max depth 8, one "
        f"render per point; reference {args.reference_spp} spp (4 stratified parts). MSE: "
        "mean over pixels and RGB channels of the squared linear difference. Machine: "
        f"{results['machine']['uptime']}",
        "",
    ]
    header = [
        "spp",
        "pair",
        "cells",
        "MSE",
        "MSE - ref noise",
        "MSE sRGB",
        "wall s",
        "device s",
        "host s",
        "load",
    ]
    for scene, entry in results["scenes"].items():
        table = [
            [
                r["spp"],
                pair_label(r["estimator"], r["sampler"]),
                r["cells"],
                r["mse"],
                r["mse_minus_ref_noise"],
                r["mse_srgb"],
                r["wall_s"],
                r["device_s"],
                r["host_s"],
                r["load_1min"],
            ]
            for r in entry["rows"]
        ]
        lines += [
            f"## {scene}",
            "",
            markdown_table(header, table),
            "",
            f"![{scene}](efficiency_{scene}.png)",
            "",
        ]
    return "\n".join(lines)


def run_study(runtime, args, argv) -> None:
    start = time.perf_counter()
    results = {"settings": {k: str(v) for k, v in vars(args).items()}, "scenes": {}}
    for scene in args.scenes:
        results["scenes"][scene] = study_scene(runtime, scene, args)
    results["machine"] = machine()
    results["seconds"] = time.perf_counter() - start
    write_json(args.out / "results.json", results)
    plot_all(results, args)
    (args.out / "report.md").write_text(report(results, args, argv) + "\n")
    print(f"done in {results['seconds']:.0f} s; wrote {args.out}/")


# ---------------------------------------------------------------------------------------------
# Voronoi / mc wall-time ratio


def best_voronoi(out: Path) -> tuple[str, str]:
    """(estimator, where it came from): the lowest-MSE Voronoi pair at the highest spp of a
    previous study of cornell-box, else DEFAULT_PERF_ESTIMATOR."""
    path = out / "results.json"
    if path.exists():
        rows = json.loads(path.read_text()).get("scenes", {}).get("cornell-box", {}).get("rows")
        if rows:
            top = max(r["spp"] for r in rows)
            best = min(
                (r for r in rows if r["spp"] == top and r["estimator"] in PERF_CANDIDATES),
                key=lambda r: r["mse"],
            )
            return best["estimator"], f"lowest MSE at {top} spp in {path}"
    return DEFAULT_PERF_ESTIMATOR, "default (no previous study)"


def run_perf_ratio(runtime, args) -> None:
    estimator, why = (
        (args.perf_estimator, "--perf-estimator") if args.perf_estimator else best_voronoi(args.out)
    )
    spp = args.spp[0]
    source = make_source(runtime, "cornell-box", args.size, args.size)
    # The Voronoi estimators that need no SPPP draw (cvor, pvor) run on uniform samples.
    entry = estimator_info(estimator)
    sampler = "independent" if entry.cells != "none" and not entry.needs_sppp else "sppp"
    pairs = [("mc", "independent"), (estimator, sampler)]
    timed_render(runtime, source, pairs[1][0], pairs[1][1], 1, 0, args.backend)  # warm-up
    runs = {pair_label(*p): [] for p in pairs}
    for _ in range(args.repeats):
        for est, sampler in pairs:
            runs[pair_label(est, sampler)].append(
                timed_render(runtime, source, est, sampler, spp, args.seed, args.backend)[1]
            )
    med = {
        label: {
            k: statistics.median(r[k] for r in rs)
            for k in ("wall_s", "device_s", "host_s", "cpu_s", "load_1min")
        }
        for label, rs in runs.items()
    }
    mc_label, vor_label = (pair_label(*p) for p in pairs)
    ratio = med[vor_label]["wall_s"] / med[mc_label]["wall_s"]
    result = {
        "size": args.size,
        "spp": spp,
        "repeats": args.repeats,
        "estimator": estimator,
        "chosen_by": why,
        "medians": med,
        "runs": runs,
        "ratio_wall": ratio,
        "target": 1.5,
        "cells": runs[vor_label][0]["cells"],
        "machine": machine(),
    }
    write_json(args.out / "perf_ratio.json", result)
    for label, m in med.items():
        print(
            f"{label:14s} wall {m['wall_s']:7.2f} s  device {m['device_s']:7.2f} s  host "
            f"{m['host_s']:7.2f} s  cpu {m['cpu_s']:7.2f} s  load {m['load_1min']:.1f}"
        )
    print(
        f"cornell-box {args.size}x{args.size} {spp} spp, medians of {args.repeats}: "
        f"{vor_label} / {mc_label} wall time = {ratio:.2f} (target <= 1.5; Voronoi cells: "
        f"{result['cells']}; {estimator} chosen by {why})"
    )
    print(f"wrote {args.out / 'perf_ratio.json'}")


def main(argv=None) -> None:
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    runtime = create_runtime()
    if args.perf_ratio:
        run_perf_ratio(runtime, args)
    else:
        run_study(runtime, args, argv)


if __name__ == "__main__":
    main()
