"""Russian roulette: time to a given MSE with and without it (not paths/s alone), and whether
its start depth or its eta'^2 scaling matter.

    python bench/roulette_study.py                  # 4 scenes, 64 x 64, spp 4 16 64 256, 8 seeds
    python bench/roulette_study.py --quick          # smoke run (8 x 8, cornell-box, 2 seeds)
    python bench/roulette_study.py --scenes mitsuba-cbox --variants off rr --seeds 4
    python bench/roulette_study.py --workers 2      # or --scheduler ADDRESS: renders on Dask

Per scene (mitsuba-cbox and cornell-box; cornell-box-glossy, whose glossy box and glass ball
make long paths; furnace, where every path runs to the maximum depth):
- a reference rendered once, without roulette: the mean of 4 mc renders over padded
  Owen-scrambled Sobol points (reference-spp / 4 each, independent scrambles; its per-pixel
  variance measured from the parts: bench/common.py), cached in OUT/references/;
- for every configuration (mc/independent, mc/sobol, vor_sn/sppp) and roulette variant
  (VARIANTS: off; rr, the shipped option; rr-from-2 and rr-from-4, the same rule from a later
  vertex (rr-from-4 is Mitsuba's rr_depth 5); rr-beta, the rule on beta alone without the
  refractions' eta'^2, only on scenes with glass), at each spp and seed: one warm render
  (one untimed render of each pair first: kernel builds and first launches are not timed),
  the pairs of a (spp, seed) round in an order rotated by the seed. Depth 8 throughout.

Measured per render: wall seconds (RenderStats.run_seconds: the render without the kernel
builds met on its thread), CPU seconds (time.process_time over the call: PoCL's threads run in
this process), rays and paths (the kernel's counters), and the MSE against the reference (mean
over pixels and RGB, less the reference's own mean variance: clrender.compare.image_errors).

Where: every render is one task (bench/common.py render_task, after an untimed warm-up of its
pair and variant in the process that renders it), in this process by default or on a Dask
cluster (--workers N: a LocalCluster here; --scheduler ADDRESS), each timed on the worker that
renders it (wall and CPU seconds of that render in that worker process, one task at a time per
worker). The images, so the MSEs, are bit-identical wherever they run. On a cluster the
workers render at once and share the cores, so wall times include waiting for the others: CPU
time, the verdicts' clock here anyway, is the render's own. A reference not yet cached is split
over the cluster by pixel ranges (bit-identical to the local one). results.json records where
the renders ran, and every row its worker and load.

Efficiency = 1 / (MSE x seconds), with the MSE a mean over the seeds and the seconds a median
(a render slowed by another process's burst does not decide it). The efficiency ratio of a
variant to "off" is (mean MSE x median seconds) of off / the same of the variant, with a 95 %
percentile bootstrap interval (seeds resampled in pairs: the same seed draws the same sample
positions with and without roulette), in CPU and in wall seconds. Where MSE x seconds is
constant (MSE ~ 1/spp, time ~ spp: independent samples at high spp) that ratio is the ratio
of times to any MSE; where it is not (Sobol points: MSE falls faster than 1/spp), times to a
target MSE say more: the (median time, mean MSE) points of a pair joined on log-log axes and
read at the target (efficiency_report.time_to_mse: interpolated between the spp that bracket
it, else the last segment extended, with its own measured slope, and said so). Two targets per
configuration: A, the MSE without roulette at the highest spp (the roulette variants usually
need a little more than that spp: extrapolated along their last segment), and B, the largest
variant MSE at the highest spp (every variant interpolated). A verdict per ratio: gain when
the interval lies above 1, loss below, else tie.

Outputs (OUT = bench/results/roulette/): results.json (every render, the summaries, ratios,
times to target, the conclusion), efficiency.png (ratios against spp with their intervals),
mse_time.png (MSE against CPU time), report.md (tables, charts, conclusion).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from pathlib import Path

# As python -m clrender does: one BLAS thread (before NumPy loads).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import (  # noqa: E402
    MAX_DEPTH,
    REFERENCE_PARTS,
    REFERENCE_SAMPLER,
    RESULTS,
    RenderTask,
    add_executor_options,
    command_line,
    executor_from_args,
    executor_record,
    machine,
    markdown_table,
    process_runtime,
    render_reference,
    render_tasks,
    write_json,
)
from efficiency_report import time_to_mse  # noqa: E402
from figures import (  # noqa: E402
    caption,
    decade_log_axis,
    draw_caption,
    report_caption,
    save_figure,
)
from scipy.stats import bootstrap  # noqa: E402

from clrender.compare import image_errors  # noqa: E402
from clrender.imageio import read_exr, write_exr  # noqa: E402
from clrender.probes import glass_shapes  # noqa: E402
from clrender.scene import load_scene  # noqa: E402

SCENES = ["mitsuba-cbox", "cornell-box", "cornell-box-glossy", "furnace"]
CONFIGS = [("mc", "independent"), ("mc", "sobol"), ("vor_sn", "sppp")]
# name: (Russian roulette on, kernel build defines, what it is)
VARIANTS = {
    "off": (False, None, "no roulette (the default, the paper's setting)"),
    "rr": (True, None, "the shipped option: pbrt-v4's rule from the second vertex"),
    "rr-from-2": (True, {"RUSSIAN_ROULETTE_MIN_DEPTH": 2}, "the same rule from the third vertex"),
    "rr-from-4": (
        True,
        {"RUSSIAN_ROULETTE_MIN_DEPTH": 4},
        "the same rule from the fifth vertex (where Mitsuba's rr_depth 5 starts)",
    ),
    "rr-beta": (
        True,
        {"RUSSIAN_ROULETTE_ETA_SCALE": 0},
        "q from beta alone, without the refractions' eta'^2 (glass scenes only)",
    ),
}
BASELINE = "off"
SHIPPED = "rr"
GLASS_ONLY = {"rr-beta"}
RESAMPLES = 2000
CLOCKS = {"cpu": "cpu_s", "wall": "wall_s"}
MAIN_CLOCK = "cpu"  # the verdicts' clock: the machine is shared, CPU time is the steadier one


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--quick", action="store_true", help="smoke run: 8 x 8, cornell-box, spp 4 16, 2 seeds"
    )
    parser.add_argument("--scenes", nargs="+", default=None)
    parser.add_argument("--variants", nargs="+", default=None, choices=list(VARIANTS))
    parser.add_argument("--size", type=int, default=None, help="width = height (default 64)")
    parser.add_argument("--spp", type=int, nargs="+", default=None, help="default 4 16 64 256")
    parser.add_argument("--seeds", type=int, default=None, help="seeds per point (default 8)")
    parser.add_argument("--seed", type=int, default=1, help="the first seed")
    parser.add_argument("--reference-spp", type=int, default=None, help="default 4096")
    parser.add_argument("--device", default=None)
    parser.add_argument("--out", type=Path, default=RESULTS / "roulette")
    parser.add_argument(
        "--rebuild",
        action="store_true",
        help="no renders: summaries, charts and report again from OUT/results.json's rows",
    )
    add_executor_options(parser)
    args = parser.parse_args(argv)
    args.scenes = args.scenes or (["cornell-box"] if args.quick else SCENES)
    quick_variants = ["off", "rr", "rr-beta"]
    args.variants = args.variants or (quick_variants if args.quick else list(VARIANTS))
    if BASELINE not in args.variants:
        args.variants.insert(0, BASELINE)
    args.size = args.size or (8 if args.quick else 64)
    args.spp = sorted(args.spp or ([4, 16] if args.quick else [4, 16, 64, 256]))
    args.seeds = args.seeds or (2 if args.quick else 8)
    args.reference_spp = args.reference_spp or (256 if args.quick else 4096)
    return args


# ---------------------------------------------------------------------------------------------
# Renders


def reference(runtime, scene: str, size: int, spp: int, folder: Path, executor=None) -> tuple:
    """(image, per-pixel variance of it, info): the no-roulette reference, cached in folder."""
    name = f"{scene}_{size}x{size}_{spp}spp_d{MAX_DEPTH}_{REFERENCE_SAMPLER}_p{REFERENCE_PARTS}"
    path, var_path = folder / f"{name}.exr", folder / f"{name}_var.exr"
    info = {"scene": scene, "spp": spp, "sampler": REFERENCE_SAMPLER, "parts": REFERENCE_PARTS}
    info.update(max_depth=MAX_DEPTH, roulette=False, path=str(path))
    if path.exists() and var_path.exists():
        image, meta = read_exr(path)
        variance = read_exr(var_path)[0]
        wall = float(meta["wall_s"])
        print(f"reference: cached {path.name}", flush=True)
        cached = True
    else:
        image, variance, wall = render_reference(
            runtime, scene, (size, size), spp, executor=executor
        )
        folder.mkdir(parents=True, exist_ok=True)
        write_exr(path, image, {"scene": scene, "spp": spp, "wall_s": wall, "roulette": 0})
        write_exr(var_path, variance, {"scene": scene, "spp": spp})
        cached = False
    info.update(cached=cached, wall_s=wall, noise=float(np.mean(variance)))
    return np.asarray(image, np.float64), float(np.mean(variance)), info


def scene_variants(scene_name: str, variants: list[str]) -> list[str]:
    """The variants that apply to a scene (the glass-only ones where it has glass)."""
    has_glass = len(glass_shapes(load_scene(scene_name))) > 0
    return [name for name in variants if name not in GLASS_ONLY or has_glass]


def render_task(scene: str, config, variant: str, spp: int, seed: int, args) -> RenderTask:
    """The render of a pair with a roulette variant (each variant its own kernel build),
    warmed up at the study's first spp where it runs."""
    roulette, defines, _ = VARIANTS[variant]
    return RenderTask(
        scene,
        (args.size, args.size),
        (config[0],),
        config[1],
        spp,
        seed,
        max_depth=MAX_DEPTH,
        russian_roulette=roulette,
        defines=tuple(sorted((defines or {}).items())),
        device=args.device,
        warmup_spp=args.spp[0],
    )


def render_row(row: dict) -> dict:
    """The study's row of a render task's row: wall_s is RenderStats.run_seconds (the render
    without the kernel builds met on its thread), cpu_s the process's CPU time over the call."""
    keys = ("spp", "seed", "cpu_s", "tracing_s", "compile_s", "paths", "rays", "redrawn_pixels")
    keys += ("nonfinite_samples", "load_1min", "worker", "workers")
    return {"wall_s": row["run_s"], **{key: row[key] for key in keys}}


def study_scene(executor, scene: str, args) -> dict:
    before = machine()
    runtime = process_runtime(args.device)
    ref, noise, ref_info = reference(
        runtime, scene, args.size, args.reference_spp, args.out / "references", executor
    )
    variants = scene_variants(scene, args.variants)
    pairs = [(config, variant) for config in CONFIGS for variant in variants]
    order = []  # (spp, seed, config, variant): a (spp, seed) round's pairs rotated by the seed
    for spp in args.spp:
        for k in range(args.seeds):
            shift = k % len(pairs)
            order += [(spp, args.seed + k, *pair) for pair in pairs[shift:] + pairs[:shift]]
    tasks = [
        render_task(scene, config, variant, spp, seed, args) for spp, seed, config, variant in order
    ]
    start = time.perf_counter()
    rows = []
    for (_, _, config, variant), (images, task_row) in zip(
        order, render_tasks(executor, tasks), strict=True
    ):
        image = images[config[0]].astype(np.float64)
        errors = image_errors(image, ref, noise)
        row = render_row(task_row)
        row.update(
            estimator=config[0],
            sampler=config[1],
            variant=variant,
            mse_raw=errors.mse,
            mse=errors.mse_minus_noise,
        )
        rows.append(row)
    print(f"{scene}: {len(rows)} renders, {time.perf_counter() - start:.0f} s", flush=True)
    return {
        "reference": ref_info,
        "variants": variants,
        "machine_before": before,
        "machine_after": machine(),
        "rows": rows,
    }


# ---------------------------------------------------------------------------------------------
# Summaries


def config_label(estimator: str, sampler: str) -> str:
    return f"{estimator}/{sampler}"


def select(rows: list[dict], config: str, variant: str, spp: int | None = None) -> list[dict]:
    chosen = [
        r
        for r in rows
        if config_label(r["estimator"], r["sampler"]) == config and r["variant"] == variant
    ]
    chosen = chosen if spp is None else [r for r in chosen if r["spp"] == spp]
    return sorted(chosen, key=lambda r: (r["spp"], r["seed"]))


def summarise(entry: dict) -> list[dict]:
    """One point per (configuration, variant, spp): MSE mean and standard error over the
    seeds, median times, paths/s and rays per path."""
    rows = entry["rows"]
    points = []
    for config in dict.fromkeys(config_label(r["estimator"], r["sampler"]) for r in rows):
        for variant in entry["variants"]:
            for spp in sorted({r["spp"] for r in rows}):
                group = select(rows, config, variant, spp)
                mse = [r["mse"] for r in group]
                wall = statistics.median(r["wall_s"] for r in group)
                paths = sum(r["paths"] for r in group)
                points.append(
                    {
                        "config": config,
                        "variant": variant,
                        "label": f"{config} {variant}",
                        "spp": spp,
                        "seeds": len(group),
                        "mse": statistics.fmean(mse),
                        "mse_se": statistics.stdev(mse) / math.sqrt(len(mse))
                        if len(mse) > 1
                        else float("nan"),
                        "wall_s": wall,
                        "cpu_s": statistics.median(r["cpu_s"] for r in group),
                        "paths_per_s": paths / len(group) / wall,
                        "paths_per_cpu_s": paths
                        / len(group)
                        / statistics.median(r["cpu_s"] for r in group),
                        "rays_per_path": sum(r["rays"] for r in group) / paths,
                    }
                )
    return points


def verdict(low: float, high: float) -> str:
    return "gain" if low > 1 else "loss" if high < 1 else "tie"


def cost_ratio(rows_a: list[dict], rows_b: list[dict], key: str, rng) -> dict:
    """Efficiency of b over a: (mean MSE x median seconds) of a / the same of b, with its 95 %
    percentile bootstrap interval (seeds resampled in pairs). The median time keeps a render
    slowed by another process's burst from deciding the ratio; the MSE is a mean, as an
    expectation must be."""
    assert [r["seed"] for r in rows_a] == [r["seed"] for r in rows_b]
    samples = tuple(
        np.array([r[k] for r in rows]) for rows in (rows_a, rows_b) for k in ("mse", key)
    )
    if len(rows_a) < 2 or min(samples[0].min(), samples[2].min()) <= 0:
        return {"ratio": None, "ci": None, "verdict": "undefined (MSE <= 0 or one seed)"}

    def statistic(mse_a, time_a, mse_b, time_b, axis=-1):
        cost_a = np.mean(mse_a, axis=axis) * np.median(time_a, axis=axis)
        cost_b = np.mean(mse_b, axis=axis) * np.median(time_b, axis=axis)
        return cost_a / np.maximum(cost_b, 1e-300)

    result = bootstrap(
        samples,
        statistic,
        n_resamples=RESAMPLES,
        paired=True,
        vectorized=True,
        axis=-1,
        confidence_level=0.95,
        method="percentile",
        rng=rng,
    )
    low, high = float(result.confidence_interval.low), float(result.confidence_interval.high)
    ratio = float(statistic(*samples))
    return {"ratio": ratio, "ci": [low, high], "verdict": verdict(low, high)}


def ratios(entry: dict, rng) -> list[dict]:
    """Efficiency ratio of every variant to "off", and of every other variant to the shipped
    rule, per configuration and spp, on both clocks."""
    rows = entry["rows"]
    points = {(p["config"], p["variant"], p["spp"]): p for p in entry["summary"]}
    out = []
    for config in dict.fromkeys(p["config"] for p in entry["summary"]):
        for spp in sorted({p["spp"] for p in entry["summary"]}):
            for variant in entry["variants"]:
                for against in (BASELINE, SHIPPED):
                    if variant in (against, BASELINE) or against not in entry["variants"]:
                        continue
                    a, b = select(rows, config, against, spp), select(rows, config, variant, spp)
                    row = {"config": config, "variant": variant, "against": against, "spp": spp}
                    for clock, key in CLOCKS.items():
                        row[clock] = cost_ratio(a, b, key, rng)
                    row["mse_ratio"] = points[(config, variant, spp)]["mse"] / max(
                        points[(config, against, spp)]["mse"], 1e-300
                    )
                    row["rays_per_path"] = points[(config, variant, spp)]["rays_per_path"]
                    row["rays_per_path_against"] = points[(config, against, spp)]["rays_per_path"]
                    out.append(row)
    return out


TARGETS = {
    # off's MSE at the highest spp: "off" is measured there; a variant that did not reach it
    # is extrapolated along its last segment (its own measured slope), said so
    "off_at_top": "the MSE without roulette at the highest spp",
    # the largest variant MSE at the highest spp: every variant interpolated between spp
    "reached_by_all": "the largest variant MSE at the highest spp",
}


def times_to_target(entry: dict) -> dict:
    """Per configuration and target (TARGETS): the target MSE, each variant's time to it
    (efficiency_report.time_to_mse: log-log interpolation between spp, or the last segment
    extended), how it was found, and its speed-up over "off" (off's time / the variant's)."""
    out = {}
    for config in dict.fromkeys(p["config"] for p in entry["summary"]):
        series = {
            v: [p for p in entry["summary"] if p["config"] == config and p["variant"] == v]
            for v in entry["variants"]
        }
        finals = [pts[-1]["mse"] for pts in series.values()]
        out[config] = {}
        for name, target in (
            ("off_at_top", series[BASELINE][-1]["mse"]),
            ("reached_by_all", max(finals)),
        ):
            if min(finals) <= 0:
                out[config][name] = {"target_mse": None}
                continue
            times = {
                v: {clock: time_to_mse(pts, target, key) for clock, key in CLOCKS.items()}
                for v, pts in series.items()
            }
            speedups = {}
            for v, t in times.items():
                base = times[BASELINE]
                speedups[v] = {
                    clock: base[clock]["seconds"] / t[clock]["seconds"]
                    if base[clock]["seconds"] and t[clock]["seconds"]
                    else None
                    for clock in CLOCKS
                }
            out[config][name] = {
                "target_mse": target,
                "times": times,
                "speedup_over_off": speedups,
            }
    return out


def headline(results: dict) -> list[dict]:
    """The table the report opens with: per scene, configuration and variant, the efficiency
    ratio to "off" at the highest spp (CPU and wall), rays per path and paths per CPU second."""
    table = []
    for scene, entry in results["scenes"].items():
        top = max(p["spp"] for p in entry["summary"])
        for r in entry["ratios"]:
            if r["spp"] != top or r["against"] != BASELINE:
                continue
            point = next(
                p
                for p in entry["summary"]
                if (p["config"], p["variant"], p["spp"]) == (r["config"], r["variant"], top)
            )
            off = next(
                p
                for p in entry["summary"]
                if (p["config"], p["variant"], p["spp"]) == (r["config"], BASELINE, top)
            )
            speed = entry["time_to_target"][r["config"]]
            speedup = {
                name: speed[name].get("speedup_over_off", {}).get(r["variant"], {}).get("cpu")
                for name in TARGETS
            }
            how = speed["off_at_top"].get("times", {}).get(r["variant"], {}).get("cpu", {})
            table.append(
                {
                    "scene": scene,
                    "config": r["config"],
                    "variant": r["variant"],
                    "spp": top,
                    "efficiency_ratio": r[MAIN_CLOCK]["ratio"],
                    "efficiency_ratio_ci": r[MAIN_CLOCK]["ci"],
                    "verdict": r[MAIN_CLOCK]["verdict"],
                    "wall_ratio": r["wall"]["ratio"],
                    "wall_ratio_ci": r["wall"]["ci"],
                    "mse_ratio": r["mse_ratio"],
                    "rays_per_path": point["rays_per_path"],
                    "rays_per_path_off": off["rays_per_path"],
                    "paths_per_cpu_s": point["paths_per_cpu_s"],
                    "paths_per_cpu_s_off": off["paths_per_cpu_s"],
                    "target_mse": speed["off_at_top"]["target_mse"],
                    "time_speedup_cpu": speedup["off_at_top"],
                    "time_how": how.get("how"),
                    "target_mse_all": speed["reached_by_all"]["target_mse"],
                    "time_speedup_cpu_all": speedup["reached_by_all"],
                }
            )
    return table


def conclusion(results: dict) -> list[str]:
    """Sentences computed from the ratios: the shipped rule's verdicts, and whether another
    start depth or beta alone beats it anywhere."""
    table = results["summary"]
    shipped = [r for r in table if r["variant"] == SHIPPED and r["efficiency_ratio"]]
    lines = []
    if shipped:
        counts = {v: sum(r["verdict"] == v for r in shipped) for v in ("gain", "tie", "loss")}
        ratios_ = [r["efficiency_ratio"] for r in shipped]
        lines.append(
            f"The shipped roulette ({SHIPPED}) against none, at the highest spp, in CPU time: "
            f"{counts['gain']} gains, {counts['tie']} ties, {counts['loss']} losses over "
            f"{len(shipped)} scene/configuration pairs; efficiency ratios "
            f"{min(ratios_):.2f} to {max(ratios_):.2f}."
        )
        for scene in dict.fromkeys(r["scene"] for r in shipped):
            items = [r for r in shipped if r["scene"] == scene]
            words = ", ".join(
                f"{r['config']} {r['efficiency_ratio']:.2f} [{r['efficiency_ratio_ci'][0]:.2f}, "
                f"{r['efficiency_ratio_ci'][1]:.2f}] ({r['verdict']})"
                for r in items
            )
            rays = items[0]["rays_per_path"] / items[0]["rays_per_path_off"]
            lines.append(f"{scene}: {words}; rays per path x{rays:.2f}.")
    others = []
    for scene, entry in results["scenes"].items():
        top = max(p["spp"] for p in entry["summary"])
        for r in entry["ratios"]:
            if r["against"] == SHIPPED and r["spp"] == top and r[MAIN_CLOCK]["ratio"]:
                others.append((scene, r))
    better = [(s, r) for s, r in others if r[MAIN_CLOCK]["verdict"] == "gain"]
    worse = [(s, r) for s, r in others if r[MAIN_CLOCK]["verdict"] == "loss"]
    if others:
        lines.append(
            f"Other rules against the shipped one (highest spp, CPU time): {len(better)} "
            f"better, {len(worse)} worse, {len(others) - len(better) - len(worse)} ties over "
            f"{len(others)} comparisons."
            + "".join(
                f" {s} {r['config']} {r['variant']}: {r[MAIN_CLOCK]['ratio']:.2f} "
                f"[{r[MAIN_CLOCK]['ci'][0]:.2f}, {r[MAIN_CLOCK]['ci'][1]:.2f}]"
                f" ({r[MAIN_CLOCK]['verdict']})."
                for s, r in better + worse
            )
        )
    # Where does any roulette pay, and is the shipped rule then the best one?
    paying = {}
    for r in table:
        if r["verdict"] == "gain":
            key = (r["scene"], r["config"])
            if key not in paying or r["efficiency_ratio"] > paying[key]["efficiency_ratio"]:
                paying[key] = r
    if paying:
        best_shipped = sum(r["variant"] == SHIPPED for r in paying.values())
        lines.append(
            f"Where some roulette beats none ({len(paying)} scene/configuration pairs of "
            f"{len({(r['scene'], r['config']) for r in table})}), the best rule is the shipped "
            f"one in {best_shipped}: "
            + "; ".join(
                f"{scene} {config} {r['variant']} {r['efficiency_ratio']:.2f}"
                for (scene, config), r in paying.items()
            )
            + "."
        )
    else:
        lines.append("No roulette rule beats none anywhere at the highest spp.")
    return lines


# ---------------------------------------------------------------------------------------------
# Figures and report

VARIANT_COLOURS = {
    "off": "0.3",
    "rr": "tab:red",
    "rr-from-2": "tab:orange",
    "rr-from-4": "tab:blue",
    "rr-beta": "tab:purple",
}
CONFIG_STYLES = {"mc/independent": ("o", "-"), "mc/sobol": ("s", "--"), "vor_sn/sppp": ("^", ":")}


def settings_caption(results: dict) -> dict:
    s = results["settings"]
    return {
        "scenes": ", ".join(results["scenes"]),
        "resolution": f"{s['size']} x {s['size']}",
        "spp": ", ".join(str(v) for v in s["spp"]),
        "seeds": f"{s['seeds']} per point ({s['first_seed']} to "
        f"{s['first_seed'] + s['seeds'] - 1})",
        "max depth": MAX_DEPTH,
        "reference": f"mc/{REFERENCE_SAMPLER} without roulette, {s['reference_spp']} spp in "
        f"{REFERENCE_PARTS} parts",
        "device": results["device"],
    }


CAPTION_WIDTH = 120


def scene_grid(count: int):
    """(figure, flat list of axes): one panel per scene, two per row, unused panels hidden."""
    columns = min(2, count)
    rows = math.ceil(count / columns)
    fig, grid = plt.subplots(
        rows,
        columns,
        figsize=(5 * columns + 2.5, 4 * rows + 1.5),
        layout="constrained",
        squeeze=False,
    )
    axes = list(grid.ravel())
    for ax in axes[count:]:
        ax.set_visible(False)
    return fig, axes[:count]


def legend_of_all(fig, axes) -> None:
    """One legend beside the axes with every labelled series of any panel (a variant that only
    some scenes have, rr-beta, is listed too), in order of first appearance."""
    entries = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    fig.legend(
        list(entries.values()),
        list(entries),
        loc="outside right upper",
        fontsize=7,
        frameon=False,
    )


def efficiency_figure(results: dict):
    scenes = list(results["scenes"])
    fig, axes = scene_grid(len(scenes))
    values = []
    for ax, scene in zip(axes, scenes, strict=True):
        entry = results["scenes"][scene]
        for i, config in enumerate(CONFIG_STYLES):
            marker, line = CONFIG_STYLES[config]
            for variant in entry["variants"]:
                pts = [
                    r
                    for r in entry["ratios"]
                    if (r["config"], r["variant"], r["against"]) == (config, variant, BASELINE)
                    and r["cpu"]["ratio"]
                ]
                if not pts:
                    continue
                x = [r["spp"] * (1 + 0.06 * (i - 1)) for r in pts]  # configs side by side
                y = [r["cpu"]["ratio"] for r in pts]
                low = [r["cpu"]["ratio"] - r["cpu"]["ci"][0] for r in pts]
                high = [r["cpu"]["ci"][1] - r["cpu"]["ratio"] for r in pts]
                values += [r["cpu"]["ci"][0] for r in pts] + [r["cpu"]["ci"][1] for r in pts]
                ax.errorbar(
                    x,
                    y,
                    yerr=[low, high],
                    marker=marker,
                    ls=line,
                    ms=4,
                    lw=1,
                    capsize=2,
                    color=VARIANT_COLOURS[variant],
                    label=f"{variant}, {config}",
                )
        ax.axhline(1.0, color="0.5", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set(title=scene, xlabel="spp", ylabel="efficiency ratio to no roulette (CPU time)")
        ax.grid(which="major", color="0.9", lw=0.6)
    positive = [v for v in values if v > 0] or [0.5, 2.0]
    spps = results["settings"]["spp"]
    for ax in axes:
        decade_log_axis(ax.yaxis, min(positive + [0.9]), max(positive + [1.1]))
        decade_log_axis(ax.xaxis, min(spps) * 0.8, max(spps) * 1.25)
    legend_of_all(fig, axes)
    text = caption(
        "Russian roulette: efficiency 1 / (MSE x CPU seconds) of each roulette variant over "
        "no roulette, against spp",
        {
            **settings_caption(results),
            "points": "(mean MSE x median CPU seconds) over the seeds without roulette / the "
            "same with the variant (MSE less the reference's variance); above 1: roulette pays",
            "error bars": f"95 % percentile bootstrap over the seeds, resampled in pairs "
            f"({RESAMPLES} resamples)",
            "variants": "; ".join(f"{k}: {VARIANTS[k][2]}" for k in results["variants"]),
        },
    )
    draw_caption(fig, text, width=CAPTION_WIDTH)
    return fig, text


def mse_time_figure(results: dict):
    scenes = list(results["scenes"])
    fig, axes = scene_grid(len(scenes))
    for ax, scene in zip(axes, scenes, strict=True):
        entry = results["scenes"][scene]
        xs, ys = [], []
        for config, (marker, line) in CONFIG_STYLES.items():
            for variant in entry["variants"]:
                pts = [
                    p
                    for p in entry["summary"]
                    if (p["config"], p["variant"]) == (config, variant) and p["mse"] > 0
                ]
                if not pts:
                    continue
                se = [0.0 if math.isnan(p["mse_se"]) else p["mse_se"] for p in pts]
                y = [p["mse"] for p in pts]
                ax.errorbar(
                    [p["cpu_s"] for p in pts],
                    y,
                    yerr=[[min(s, 0.999 * v) for s, v in zip(se, y, strict=True)], se],
                    marker=marker,
                    ls=line,
                    ms=4,
                    lw=1,
                    capsize=2,
                    color=VARIANT_COLOURS[variant],
                    label=f"{variant}, {config}",
                )
                xs += [p["cpu_s"] for p in pts]
                ys += y
        ax.set_xscale("log")
        ax.set_yscale("log")
        if xs:
            decade_log_axis(ax.xaxis, min(xs), max(xs))
            decade_log_axis(ax.yaxis, min(ys), max(ys))
        ax.set(title=scene, xlabel="CPU seconds per render (median)", ylabel="MSE")
        ax.grid(which="major", color="0.9", lw=0.6)
    legend_of_all(fig, axes)
    text = caption(
        "Russian roulette: whole-image MSE against CPU time per render",
        {
            **settings_caption(results),
            "points": "mean MSE over the seeds less the reference's variance, median CPU time",
            "error bars": "+- 1 standard error of the mean over the seeds",
        },
    )
    draw_caption(fig, text, width=CAPTION_WIDTH)
    return fig, text


def fmt(value, digits: int = 3) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}g}"


def report(results: dict, captions: dict) -> str:
    s = results["settings"]
    lines = [
        "# Russian roulette: time to a given MSE",
        "",
        f"Command: `{s['command']}`. Device: {results['device']}. Machine load before / after: "
        + ", ".join(
            f"{scene} {e['machine_before']['load_1_5_15'][0]:.1f} / "
            f"{e['machine_after']['load_1_5_15'][0]:.1f}"
            for scene, e in results["scenes"].items()
        )
        + ".",
        "",
        "## Conclusion",
        "",
        *[f"- {line}" for line in results["conclusion"]],
        "",
        f"## Efficiency ratio to no roulette at {max(s['spp'])} spp",
        "",
        "Efficiency = 1 / (MSE x seconds); ratio = (mean MSE x median CPU seconds) over the "
        "seeds without roulette / the same with the variant, with its 95 % bootstrap interval "
        "over seeds (resampled in pairs); wall: the same in wall seconds. Speed-up: the CPU "
        "time without roulette to a target MSE / the variant's, each time found on the "
        "log-log line through the (median CPU time, mean MSE) points of successive spp "
        f"(interpolated, or the last segment extended: 'how'). Target A: {TARGETS['off_at_top']}; "
        f"target B: {TARGETS['reached_by_all']}. Paths per CPU second: per render, median.",
        "",
        markdown_table(
            [
                "scene",
                "config",
                "variant",
                "ratio (CPU)",
                "95 % CI",
                "verdict",
                "ratio (wall)",
                "MSE ratio",
                "rays/path",
                "rays/path off",
                "paths/CPU s",
                "paths/CPU s off",
                "target A",
                "speed-up to A (CPU)",
                "how",
                "target B",
                "speed-up to B (CPU)",
            ],
            [
                [
                    r["scene"],
                    r["config"],
                    r["variant"],
                    fmt(r["efficiency_ratio"]),
                    f"[{fmt(r['efficiency_ratio_ci'][0])}, {fmt(r['efficiency_ratio_ci'][1])}]"
                    if r["efficiency_ratio_ci"]
                    else "-",
                    r["verdict"],
                    fmt(r["wall_ratio"]),
                    fmt(r["mse_ratio"]),
                    fmt(r["rays_per_path"]),
                    fmt(r["rays_per_path_off"]),
                    fmt(r["paths_per_cpu_s"]),
                    fmt(r["paths_per_cpu_s_off"]),
                    fmt(r["target_mse"]),
                    fmt(r["time_speedup_cpu"]),
                    r["time_how"] or "-",
                    fmt(r["target_mse_all"]),
                    fmt(r["time_speedup_cpu_all"]),
                ]
                for r in results["summary"]
            ],
        ),
        "",
        "![efficiency](efficiency.png)",
        "",
        report_caption(captions["efficiency"]),
        "",
        "![mse against time](mse_time.png)",
        "",
        report_caption(captions["mse_time"]),
        "",
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------


def main(argv=None) -> dict:
    args = parse_args(argv)
    if args.rebuild:
        results = json.loads((args.out / "results.json").read_text())
    else:
        with executor_from_args(args) as executor:
            results = run(args, argv, executor)
    analyse(results, args.out)
    print("\n".join(results["conclusion"]))
    return results


def run(args, argv, executor) -> dict:
    """Every render of the study, on the executor; results.json written after each scene."""
    runtime = process_runtime(args.device)  # the process's runtime: programs built once
    results = {
        "settings": {
            "size": args.size,
            "spp": args.spp,
            "seeds": args.seeds,
            "first_seed": args.seed,
            "reference_spp": args.reference_spp,
            "configs": [config_label(*c) for c in CONFIGS],
            "max_depth": MAX_DEPTH,
            "command": command_line("roulette_study.py", argv),
        },
        "device": runtime.describe(),
        "executor": executor_record(executor, args),
        "variants": args.variants,
        "scenes": {},
    }
    for scene in args.scenes:
        results["scenes"][scene] = study_scene(executor, scene, args)
        write_json(args.out / "results.json", results)
    return results


def analyse(results: dict, out: Path) -> None:
    """Summaries, ratios, times to target, the conclusion, the charts and the report, from the
    renders' rows (again with --rebuild)."""
    rng = np.random.default_rng(20240613)
    for entry in results["scenes"].values():
        entry["summary"] = summarise(entry)
        entry["ratios"] = ratios(entry, rng)
        entry["time_to_target"] = times_to_target(entry)
    results["references"] = [e["reference"] for e in results["scenes"].values()]
    results["summary"] = headline(results)
    results["conclusion"] = conclusion(results)
    captions = {}
    for name, make in (("efficiency", efficiency_figure), ("mse_time", mse_time_figure)):
        fig, captions[name] = make(results)
        save_figure(fig, out / f"{name}.png", dpi=100)
        plt.close(fig)
    write_json(out / "results.json", results)
    (out / "report.md").write_text(report(results, captions))


if __name__ == "__main__":
    main()
