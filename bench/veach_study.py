"""Where each estimator wins or loses on Veach's MIS scene (scenes/veach-mis.toml).

    python bench/veach_study.py                # 320 x 180, 256 spp, 4 seeds, 4096 spp reference
    python bench/veach_study.py --quick        # a smoke run of a few seconds
    python bench/veach_study.py --workers 2    # or --scheduler ADDRESS: the renders on Dask

Every (estimator, sampler) pair renders the scene with several seeds; each render's error is
the MSE per pixel against a cached reference (bench/common.py: the mean of independent mc
renders over padded Owen-scrambled Sobol, whose own per-pixel variance is measured) less that
reference's noise, averaged over the pixels of each REGION. The regions come from the scene's
geometry (clrender.probes), never from pixel numbers:

- "outline <light>": pixels the analytic image outline of a spherical light crosses (the
  projected silhouette circle covers some but not all of the pixel);
- "<light> on <plate>": a square window around the light's glossy reflection on a plate
  (clrender.probes.glossy_reflection_pixel), limited to pixels that see that plate;
- "rest of <plate>": the plate's other pixels;
- "floor", "back wall": the diffuse surfaces' pixels; "whole image": every pixel.

Per region and pair: the mean over seeds of the MSE (less reference noise) with its standard
error, and the ratio to mc/sobol and to mc_n/sppp: the geometric mean over seeds of the
per-seed ratio, with a 95 % Student-t interval of its log over the seeds (seed s of both pairs
pairs up; the SPPP estimators share one trace per seed). A win if the whole interval is below
1, a loss if above, else a tie. The SPPP estimators mc_n, vor_sn and fvor come from one
render (one trace, several estimators), so their time is that shared render's.
Each (render, seed) is one task (bench/common.py render_task), in this process by default or
on a Dask cluster (--workers N, --scheduler ADDRESS); its wall and CPU seconds are taken in the
process that renders it, after an untimed warm-up of that render there (kernel builds). The
region MSEs are bit-identical wherever the renders run; on a cluster the workers share the
cores, so wall times include waiting for the other workers (CPU time is the render's own).
A reference not yet cached is split over the cluster by pixel ranges (bit-identical).
Writes results.json and report.md under bench/results/veach_study/ (or --out).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from common import (
    RESULTS,
    RenderTask,
    add_executor_options,
    command_line,
    executor_from_args,
    executor_record,
    machine,
    markdown_table,
    pair_label,
    process_runtime,
    reference,
    render_tasks,
    write_json,
)
from scipy import stats

from clrender.errors import ParameterError
from clrender.probes import (
    glossy_reflection_pixel,
    pixel_hits,
    polygon_pixel_coverage,
    shape_materials,
    sphere_outline,
)
from clrender.scene import load_scene

SCENE = "veach-mis"
OUT = RESULTS / "veach_study"
# Renders: one estimator, or several sharing one trace (the SPPP family).
RENDERS = [
    (("mc",), "independent"),
    (("mc",), "sobol"),
    (("mc_n", "vor_sn", "fvor"), "sppp"),
    (("pvor",), "sobol"),
]
BASELINES = ("mc/sobol", "mc_n/sppp")
PLATES = ("Smooth", "Glossy", "Rough", "SuperRough")
DIFFUSE_SURFACES = {"floor": "mesh4 Diffuse", "back wall": "mesh5 Diffuse"}
# Half-width of a reflection window, in pixels of a 320-pixel-wide image (scaled with width).
REFLECTION_HALF_WIDTH_320 = 3
CONFIDENCE = 0.95


# ---------------------------------------------------------------------------------------------
# Regions from the geometry


def light_names(scene) -> list[str]:
    """Names of the spherical lights, emitter order."""
    return [scene.sphere_names[int(e["index"])] for e in scene.emitters]


def outline_mask(scene, width: int, height: int, emitter: int) -> np.ndarray:
    """(H, W) pixels the light's projected silhouette circle partly covers."""
    polygon = sphere_outline(scene, width, height, int(scene.emitters[emitter]["index"]))
    low = np.clip(np.floor(polygon.min(axis=0)).astype(int), 0, [width - 1, height - 1])
    high = np.clip(np.floor(polygon.max(axis=0)).astype(int), 0, [width - 1, height - 1])
    mask = np.zeros((height, width), bool)
    for y in range(low[1], high[1] + 1):
        for x in range(low[0], high[0] + 1):
            mask[y, x] = 0.0 < polygon_pixel_coverage(polygon, x, y) < 1.0 - 1e-9
    return mask


def regions(scene, width: int, height: int) -> dict[str, np.ndarray]:
    """Named (H, W) masks of the study's regions (see the module docstring)."""
    shape, _ = pixel_hits(scene, width, height)
    materials = np.where(shape >= 0, shape_materials(scene)[np.maximum(shape, 0)], -1)
    lights = light_names(scene)
    found = {}
    for e, name in enumerate(lights):
        found[f"outline {name}"] = outline_mask(scene, width, height, e)
    half = max(1, round(REFLECTION_HALF_WIDTH_320 * width / 320))
    for plate in PLATES:
        on_plate = (materials == scene.material_names.index(plate)).all(axis=-1)
        windows = np.zeros_like(on_plate)
        for e, name in enumerate(lights):
            try:
                probe = glossy_reflection_pixel(scene, width, height, emitter=e, material=plate)
            except ParameterError:
                continue
            window = np.zeros_like(on_plate)
            window[
                max(0, probe.y - half) : probe.y + half + 1,
                max(0, probe.x - half) : probe.x + half + 1,
            ] = True
            found[f"{name} on {plate}"] = window & on_plate
            windows |= window
        found[f"rest of {plate}"] = on_plate & ~windows
    for label, quad in DIFFUSE_SURFACES.items():
        found[label] = (shape == scene.quad_names.index(quad)).all(axis=-1)
    found["whole image"] = np.ones((height, width), bool)
    return found


# ---------------------------------------------------------------------------------------------
# Renders and errors


def region_mse(image, ref, ref_var, masks) -> dict[str, float | None]:
    """Per region: mean over its pixels and channels of the squared error, less the mean of
    the reference's own variance there (None for an empty region)."""
    sq = ((image - ref) ** 2).mean(axis=-1)
    noise = ref_var.mean(axis=-1)
    return {
        name: float(sq[m].mean() - noise[m].mean()) if m.any() else None
        for name, m in masks.items()
    }


def run_renders(executor, args, ref, ref_var, masks, log=print) -> list[dict]:
    """One row per (pair, seed): region MSEs and the time of the render it came from (every
    (seed, render) a task on the executor)."""
    tasks = [
        RenderTask(SCENE, (args.width, args.height), estimators, sampler, args.spp, seed)
        for seed in args.seeds
        for estimators, sampler in RENDERS
    ]
    rows = []
    for task, (images, timing) in zip(tasks, render_tasks(executor, tasks), strict=True):
        estimators, sampler = task.estimators, task.sampler
        for name in estimators:
            rows.append(
                {
                    "pair": pair_label(name, sampler),
                    "seed": task.seed,
                    "shared_with": [pair_label(e, sampler) for e in estimators],
                    "wall_s": timing["call_s"],
                    "cpu_s": timing["cpu_s"],
                    "worker": timing["worker"],
                    "workers": timing["workers"],
                    "region_mse": region_mse(images[name].astype(np.float64), ref, ref_var, masks),
                }
            )
        log(
            f"seed {task.seed} {'+'.join(estimators)}/{sampler}: {timing['call_s']:.1f} s wall, "
            f"{timing['cpu_s']:.1f} s CPU on {timing['worker']}; whole-image MSE "
            + ", ".join(f"{r['region_mse']['whole image']:.4g}" for r in rows[-len(estimators) :])
        )
    return rows


# ---------------------------------------------------------------------------------------------
# Summaries


def summarise(rows: list[dict], region_names: list[str]) -> dict:
    """{pair: {region: {mse, mse_se, vs <baseline>: {ratio, low, high, verdict}}}, time}."""
    pairs = list(dict.fromkeys(r["pair"] for r in rows))
    by_pair = {
        p: sorted((r for r in rows if r["pair"] == p), key=lambda r: r["seed"]) for p in pairs
    }
    table = {}
    for pair in pairs:
        entry = {
            "wall_s": float(np.median([r["wall_s"] for r in by_pair[pair]])),
            "cpu_s": float(np.median([r["cpu_s"] for r in by_pair[pair]])),
            "shared_with": by_pair[pair][0]["shared_with"],
            "regions": {},
        }
        for region in region_names:
            values = np.array([r["region_mse"][region] for r in by_pair[pair]], dtype=float)
            if np.isnan(values).any():
                continue
            cell = {
                "mse": float(values.mean()),
                "mse_se": float(values.std(ddof=1) / np.sqrt(len(values)))
                if len(values) > 1
                else None,
                "mse_per_seed": values.tolist(),
            }
            for base in BASELINES:
                if base in by_pair:
                    other = np.array([r["region_mse"][region] for r in by_pair[base]], float)
                    cell[f"vs {base}"] = ratio_interval(values, other)
            entry["regions"][region] = cell
        table[pair] = entry
    return table


def ratio_interval(values: np.ndarray, baseline: np.ndarray) -> dict:
    """Geometric mean of the per-seed ratios values / baseline with a CONFIDENCE Student-t
    interval of its log; 'win' if the interval lies below 1, 'loss' above, else 'tie'
    (also when a per-seed MSE is not positive, the reference noise then dominating)."""
    if (values <= 0).any() or (baseline <= 0).any() or len(values) < 2:
        return {"ratio": None, "low": None, "high": None, "verdict": "tie"}
    logs = np.log(values / baseline)
    mean = logs.mean()
    half = stats.t.ppf(0.5 + CONFIDENCE / 2, len(logs) - 1) * logs.std(ddof=1) / np.sqrt(len(logs))
    low, high = float(np.exp(mean - half)), float(np.exp(mean + half))
    verdict = "win" if high < 1.0 else "loss" if low > 1.0 else "tie"
    return {"ratio": float(np.exp(mean)), "low": low, "high": high, "verdict": verdict}


def ratio_cell(cell: dict | None, pair: str, base: str) -> str:
    """'ratio [low, high]' with W (win) or L (loss); '-' for the baseline itself."""
    if pair == base:
        return "-"
    key = f"vs {base}"
    if cell is None or key not in cell or cell[key]["ratio"] is None:
        return "n/a"
    r = cell[key]
    mark = {"win": " **W**", "loss": " L", "tie": ""}[r["verdict"]]
    return f"{r['ratio']:.2g} [{r['low']:.2g}, {r['high']:.2g}]{mark}"


def report(results: dict, argv) -> str:
    table = results["table"]
    pairs = list(table)
    regions = results["region_pixels"]
    ref = results["reference"]
    lines = [
        "# Veach's MIS scene: where each estimator wins or loses",
        "",
        f"Command: `{command_line('veach_study.py', argv)}`",
        "",
        f"{results['size'][0]} x {results['size'][1]}, {results['spp']} spp, seeds "
        f"{results['seeds']}, max depth {ref['max_depth']}; reference: {ref['spp']} spp mc over "
        f"{ref['sampler']} ({ref['parts']} parts), its own noise (mean per-pixel variance) "
        f"{results['reference_noise']:.3g}, subtracted from every MSE. Device: "
        f"{results['device']}.",
        "",
        "## Mean MSE (less reference noise) +- standard error over seeds",
        "",
    ]
    rows = []
    for region, count in regions.items():
        row = [region, count, f"{results['region_reference_noise'][region]:.2g}"]
        for pair in pairs:
            cell = table[pair]["regions"].get(region)
            row.append("n/a" if cell is None else f"{cell['mse']:.3g} +- {cell['mse_se'] or 0:.2g}")
        rows.append(row)
    lines += [markdown_table(["region", "pixels", "reference noise", *pairs], rows), ""]
    for base in BASELINES:
        lines += [
            f"## MSE ratio to {base} (geometric mean over seeds, {CONFIDENCE:.0%} interval; "
            "**W** win: interval below 1, L loss: above)",
            "",
        ]
        rows = [
            [region, *(ratio_cell(table[p]["regions"].get(region), p, base) for p in pairs)]
            for region in regions
        ]
        lines += [markdown_table(["region", *pairs], rows), ""]
    lines += ["## Render time (median over seeds)", ""]
    rows = [
        [p, table[p]["wall_s"], table[p]["cpu_s"], " + ".join(table[p]["shared_with"])]
        for p in pairs
    ]
    lines += [
        markdown_table(["pair", "wall s", "CPU s", "one render of"], rows),
        "",
        f"Renders ran in {results['executor']['where']}, each timed "
        f"{results['executor']['timed']}. Machine: {results['machine']['uptime']}",
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# Main


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, nargs=2, default=[320, 180], metavar=("W", "H"))
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--reference-spp", type=int, default=4096)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--out", type=Path, default=OUT)
    add_executor_options(parser)
    parser.add_argument(
        "--quick", action="store_true", help="smoke run: 32 x 18, 4 spp, 16 spp reference, 2 seeds"
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.size, args.spp, args.reference_spp, args.seeds = [32, 18], 4, 16, [1, 2]
    args.width, args.height = args.size
    return args


def main(argv=None) -> None:
    args = parse_args(argv)
    with executor_from_args(args) as executor:
        run(args, executor, argv)


def run(args, executor, argv) -> None:
    start = time.perf_counter()
    runtime = process_runtime()
    scene = load_scene(SCENE)
    masks = regions(scene, args.width, args.height)
    ref, ref_var, ref_info = reference(
        runtime, SCENE, tuple(args.size), args.reference_spp, executor=executor
    )
    rows = run_renders(executor, args, ref, ref_var, masks)
    results = {
        "size": args.size,
        "spp": args.spp,
        "seeds": args.seeds,
        "device": runtime.describe(),
        "executor": executor_record(executor, args),
        "reference": ref_info,
        "reference_noise": float(ref_var.mean()),
        "region_pixels": {name: int(m.sum()) for name, m in masks.items()},
        "region_reference_noise": {
            name: float(ref_var.mean(axis=-1)[m].mean()) for name, m in masks.items()
        },
        "table": summarise(rows, list(masks)),
        "renders": rows,
        "machine": machine(),
        "seconds": time.perf_counter() - start,
    }
    write_json(args.out / "results.json", results)
    (args.out / "report.md").write_text(report(results, argv) + "\n")
    print(f"done in {results['seconds']:.0f} s; wrote {args.out}/")


if __name__ == "__main__":
    main()
