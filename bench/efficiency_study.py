"""Accuracy against speed: whole-image MSE against wall and CPU time for every sampler x
estimator configuration on the Cornell boxes, several seeds per point, with Mitsuba 3 as an
optional peer on its own Cornell box; and the Voronoi-over-mc wall-time ratio.

    python bench/efficiency_study.py [--quick] [--scenes mitsuba-cbox ...] [--size 256]
        [--spp 16 64 256] [--seeds 3] [--reference-spp 4096] [--peer auto|off] [--out DIR]
        [--workers N | --scheduler ADDRESS]
    python bench/efficiency_study.py --perf-ratio [--perf-estimator NAME] [--repeats 3]

Optional peer: `pip install mitsuba` and `apt-get install -y libllvm19` (bench/mitsuba_peer.py;
not a clrender dependency). Without it the report says the peer was not run.

Default mode, per scene (mitsuba-cbox, cornell-box, cornell-box-glossy):
- a cached reference (bench/common.py: mc over padded Owen-scrambled Sobol samples, 4 parts of
  reference-spp / 4 each, independent scrambles; its per-pixel variance measured from the
  parts);
- CONFIGS (below) at each spp with --seeds seeds (seed, seed + 1, ...): for each (spp, seed) a
  round over every configuration, the order rotated by the seed, after one untimed warm-up
  render of each configuration at the first spp (kernel builds are not timed);
- on mitsuba-cbox with Mitsuba importable (--peer auto): Mitsuba's built-in Cornell box (the
  scene mitsuba-cbox was generated from) at the same size and spp with its samplers
  independent, stratified, multijitter and ldsampler, max_depth 9 (= clrender's depth 8), box
  filter, the same seeds, interleaved with clrender's renders in each round, one untimed
  warm-up per sampler and spp, scored against Mitsuba's own 4096-spp reference (ldsampler,
  4 parts, variance measured) so that systematic differences between the renderers do not
  count as error; the MSE between the two references is reported beside.
- a time budget: a configuration whose render at the next spp is predicted (its median wall
  time at the last spp x the spp ratio) to take more than --max-seconds (default 60) is not
  rendered there or above, and the report lists it (ivor_sn's host tessellation of the whole
  image takes about 35 s at 64 spp, 256 x 256, on two cores).
MSE of a render = mean over pixels and RGB of (render - reference)^2 less the reference's mean
variance; per point mean +- standard error over seeds, median wall time of the whole call and
median CPU time (time.process_time: PoCL's and Dr.Jit's threads run in this process).
Time to MSE 1e-4 and the targets: bench/efficiency_report.py. Outputs (default
bench/results/efficiency_study/): results.json (every render's row and the summaries; a scene
run again replaces its entry, other scenes are kept; written after every (spp, seed) round, so
a killed run keeps its finished rounds and the same command resumes from them),
efficiency_<scene>.png (MSE against wall and CPU time, log-log, error bars), report.md.

Where the renders run: each clrender render is one task (bench/common.py render_task: the
whole render of one (scene, configuration, spp, seed), after an untimed warm-up of that
configuration at the first spp in the process that renders it), in this process by default or
on a Dask cluster (--workers N: a LocalCluster of N processes here; --scheduler ADDRESS). A
round's renders run as tasks at once, each timed on its worker: the wall and CPU time of that
render in that worker process (one task at a time per worker). The images, so the MSEs, are
bit-identical wherever they run; the times are not: workers render different configurations
at once and share the cores, so a render's wall time on a cluster includes waiting for the
others, and the efficiency's clock there is CPU time (the report's times to target and
conclusions say which clock; results.json records the executor, and every row its worker and
load). Mitsuba's peer renders stay in this process, after the round's clrender tasks finish
(not interleaved with them). A reference not yet cached is split over the whole cluster by
pixel ranges (clrender.cluster.render_on: bit-identical to the local one, so the cached file
serves both), timed by this process's wall clock. The time budget (--max-seconds) predicts
from wall times wherever they were taken. --perf-ratio runs in this process only.

Configurations: mc over every sampler; mc_n only over the SPPP samplers, because over a
fixed-count sampler N = n and mc_n is mc exactly (same image); vor_sn and fvor over sppp and
sppp-sobol (they need auxiliary nuclei); pvor over stratified and sobol (the render settings add
a random toroidal shift per pixel, which makes it unbiased there); ivor_sn over sppp-sobol and
sppp (it needs Poisson counts).

--perf-ratio: the Voronoi-over-mc wall-time figure. The authors' Cornell box at 256 x 256 and
256 spp: mc over independent samples against the best Voronoi estimator (by default the one of vor,
vor_sn, fvor, pvor -- the Voronoi estimators the device backend computes -- with the lowest MSE at
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

import common  # noqa: E402
import efficiency_report  # noqa: E402
import numpy as np  # noqa: E402
from common import (  # noqa: E402
    RESULTS,
    RenderTask,
    add_executor_options,
    command_line,
    default_backend,
    executor_from_args,
    executor_record,
    image_errors,
    machine,
    make_source,
    pair_label,
    process_runtime,
    reference,
    render_tasks,
    timed_render,
    write_json,
)
from mitsuba_peer import SAMPLERS as MITSUBA_SAMPLERS  # noqa: E402
from mitsuba_peer import MitsubaPeer  # noqa: E402

from clrender.cluster import DaskExecutor  # noqa: E402
from clrender.estimators import ESTIMATORS, estimator_info  # noqa: E402

SCENES = ["mitsuba-cbox", "cornell-box", "cornell-box-glossy", "veach-mis"]
PEER_SCENE = "mitsuba-cbox"
FIXED_COUNT = ["independent", "stratified", "sobol", "zsobol"]
SPPP = ["sppp", "sppp-sobol"]
CONFIGS = (
    [("mc", s) for s in FIXED_COUNT + SPPP]
    + [("mc_n", s) for s in SPPP]
    + [(e, s) for e in ("vor_sn", "fvor") for s in SPPP]
    + [("pvor", "stratified"), ("pvor", "sobol")]
    + [("ivor_sn", "sppp-sobol"), ("ivor_sn", "sppp")]
)
DEFAULT_PERF_ESTIMATOR = "vor_sn"
# The perf-ratio candidates: the estimators whose cells the device backend computes (vor, vor_sn,
# fvor over SPPP cells, pvor over torus cells); cvor is left out as biased (the paper drops it
# too).
PERF_CANDIDATES = tuple(name for name, entry in ESTIMATORS.items() if entry.device_sums)
WARMUP_SEED = 999


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: 24 x 24, spp 4 16, 2 seeds, reference 64 (perf: 32 x 32)",
    )
    parser.add_argument("--scenes", nargs="+", default=SCENES)
    parser.add_argument(
        "--size", type=int, default=None, help="width = height (default 256; --quick 24)"
    )
    parser.add_argument(
        "--spp",
        type=int,
        nargs="+",
        default=None,
        help="perfect squares and powers of two (stratified, zsobol); default 16 64 256",
    )
    parser.add_argument("--seeds", type=int, default=None, help="seeds per point (default 3)")
    parser.add_argument("--seed", type=int, default=1, help="the first seed")
    parser.add_argument("--reference-spp", type=int, default=None, help="default 4096")
    parser.add_argument(
        "--configs", nargs="+", default=None, help="only these estimator/sampler labels"
    )
    parser.add_argument(
        "--max-seconds",
        type=float,
        default=60.0,
        help="a configuration whose predicted render time at the next spp exceeds this is not "
        "rendered there (nor above); default 60",
    )
    parser.add_argument(
        "--peer",
        choices=("auto", "off"),
        default="auto",
        help="Mitsuba 3 on mitsuba-cbox when it imports (auto, default) or never",
    )
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
    add_executor_options(parser)
    args = parser.parse_args(argv)
    if args.perf_ratio and (args.workers is not None or args.scheduler is not None):
        parser.error("--perf-ratio times its renders in this process: no --workers/--scheduler")
    if args.perf_ratio:
        args.size = args.size or (32 if args.quick else 256)
        args.spp = args.spp or ([16] if args.quick else [256])
        args.repeats = args.repeats or (1 if args.quick else 3)
    args.size = args.size or (24 if args.quick else 256)
    args.spp = args.spp or ([4, 16] if args.quick else [16, 64, 256])
    args.seeds = args.seeds or (2 if args.quick else 3)
    args.reference_spp = args.reference_spp or (64 if args.quick else 4096)
    return args


def configs(args) -> list[tuple[str, str]]:
    chosen = CONFIGS
    if args.configs:
        chosen = [c for c in CONFIGS if pair_label(*c) in args.configs]
        unknown = set(args.configs) - {pair_label(*c) for c in chosen}
        if unknown:
            raise SystemExit(f"unknown configurations {sorted(unknown)}; known: {CONFIGS}")
    return chosen


# ---------------------------------------------------------------------------------------------
# MSE against time


def start_peer(scene: str, args) -> MitsubaPeer | None:
    if scene != PEER_SCENE or args.peer == "off":
        return None
    peer = MitsubaPeer(args.size, args.size)
    print(f"mitsuba peer: {peer.status()}", flush=True)
    return peer


def study_scene(executor, scene: str, args, argv, previous=None, save=None) -> dict:
    """One scene's study, its renders on the executor. previous: this scene's entry from an
    interrupted run; its rows are kept, and its (spp, seed) rounds are not rendered again when
    its settings match. save(entry) is called after every round, so a killed run loses at most
    one round."""
    before = machine()
    runtime = process_runtime()
    size = (args.size, args.size)
    ref, ref_var, ref_info = reference(runtime, scene, size, args.reference_spp, executor=executor)
    chosen = configs(args)
    peer = start_peer(scene, args)
    use_peer = peer is not None and peer.available
    entry = {
        "settings": {
            "size": args.size,
            "spp": args.spp,
            "seeds": args.seeds,
            "first_seed": args.seed,
            "reference_spp": args.reference_spp,
            "command": command_line("efficiency_study.py", argv),
        },
        "reference": ref_info,
        "reference_noise": float(ref_var.mean()),
        "device": runtime.describe(),
        "executor": executor_record(executor, args),
        "machine_before": before,
        "complete": False,
    }
    entry["settings"]["configs"] = [pair_label(*c) for c in chosen]
    entry["settings"]["backend"] = args.backend
    entry["settings"]["peer"] = args.peer
    kept = resumable_rows(previous, entry["settings"])
    entry["runs"] = (previous.get("runs", []) if kept else []) + [
        {"started": time.strftime("%Y-%m-%d %H:%M:%S"), "machine_before": before}
    ]
    if peer is not None:
        entry["peer"] = {"status": peer.status()}
    refs = {"clrender": (ref, ref_var)}
    if use_peer:
        mref, mref_var, mref_info = peer.reference(args.reference_spp, common.REFERENCE_DIR)
        refs["mitsuba"] = (mref, mref_var)
        between = float(((mref - ref) ** 2).mean())
        entry["peer"].update(
            reference=mref_info,
            reference_noise=float(mref_var.mean()),
            reference_mse_between_raw=between,
            reference_mse_between=between - float(mref_var.mean()) - float(ref_var.mean()),
            reference_means={"clrender": float(ref.mean()), "mitsuba": float(mref.mean())},
        )
    rows: list[dict] = list(kept)
    done = {(r["spp"], r["seed"]) for r in kept}
    if kept:
        print(f"{scene}: resuming, {len(done)} rounds kept from the interrupted run", flush=True)
    entry["skipped"] = []
    entry["rows"] = rows
    for spp in args.spp:
        now = within_budget(chosen, rows, spp, args.max_seconds, entry["skipped"])
        seeds = [args.seed + k for k in range(args.seeds) if (spp, args.seed + k) not in done]
        if use_peer and seeds:
            for sampler in MITSUBA_SAMPLERS:
                peer.render(sampler, spp, WARMUP_SEED)
        for seed in seeds:
            k = seed - args.seed
            items = [("clrender", c) for c in now]
            if use_peer:  # Mitsuba's samplers spread evenly among clrender's configurations
                step = max(1, len(items) // len(MITSUBA_SAMPLERS))
                for i, sampler in enumerate(MITSUBA_SAMPLERS):
                    items.insert(min(len(items), i * (step + 1) + step), ("mitsuba", sampler))
            shift = k % len(items)
            order = items[shift:] + items[:shift]
            rows += render_round(executor, scene, peer, refs, order, spp, seed, args)
            if save is not None:
                save(entry)
    entry["machine_after"] = machine()
    entry["complete"] = True
    entry["summary"] = efficiency_report.summarise(rows)
    entry["time_to_target"] = efficiency_report.times_to_target(entry["summary"])
    if use_peer:
        entry["targets"] = efficiency_report.targets(entry)
    return entry


def resumable_rows(previous: dict | None, settings: dict) -> list[dict]:
    """The rows of an interrupted run of the same study (equal settings but the command line);
    [] when there is none or it finished."""
    if not previous or previous.get("complete", True):
        return []
    same = {k: v for k, v in previous.get("settings", {}).items() if k != "command"}
    if same != {k: v for k, v in settings.items() if k != "command"}:
        return []
    return previous.get("rows", [])  # saved after whole rounds only


def within_budget(chosen, rows, spp, max_seconds, skipped) -> list[tuple[str, str]]:
    """The configurations to render at spp: those whose predicted time (median wall at the
    highest spp rendered so far, scaled by the spp ratio) is within max_seconds. The others
    are recorded in skipped and, having no row at this spp, are not rendered above it either."""
    keep = []
    previous = max((r["spp"] for r in rows), default=None)
    for config in chosen:
        if previous is None:
            keep.append(config)
            continue
        walls = [
            r["call_s"]
            for r in rows
            if (r["estimator"], r["sampler"]) == config and r["spp"] == previous
        ]
        if not walls:  # skipped before
            continue
        wall = statistics.median(walls)
        predicted = wall * spp / previous
        if predicted <= max_seconds:
            keep.append(config)
            continue
        skipped.append(
            {
                "config": pair_label(*config),
                "spp": spp,
                "predicted_s": predicted,
                "from": f"median {wall:.1f} s at {previous} spp",
            }
        )
        print(
            f"skip {pair_label(*config)} at {spp} spp and above: predicted {predicted:.0f} s per "
            f"render > --max-seconds {max_seconds:g}",
            flush=True,
        )
    return keep


def render_round(executor, scene, peer, refs, items, spp, seed, args) -> list[dict]:
    """The rows of one (spp, seed) round. In this process the renders run one after another in
    the items' order (Mitsuba's among clrender's); on a cluster clrender's renders run as tasks
    at once, then Mitsuba's here, so the peer never shares the cores with a task of this round."""
    if not isinstance(executor, DaskExecutor):
        return [
            one_render(executor, scene, peer, refs, who, what, spp, seed, args)
            for who, what in items
        ]
    ours = [what for who, what in items if who == "clrender"]
    tasks = [clrender_task(scene, what, spp, seed, args) for what in ours]
    rows = [
        scored_row(images[what[0]], row, refs, "clrender", pair_label(*what))
        for what, (images, row) in zip(ours, render_tasks(executor, tasks), strict=True)
    ]
    return rows + [
        one_render(executor, scene, peer, refs, who, what, spp, seed, args)
        for who, what in items
        if who == "mitsuba"
    ]


def clrender_task(scene: str, config: tuple[str, str], spp: int, seed: int, args) -> RenderTask:
    """The render task of a configuration (warmed up at the study's first spp)."""
    estimator, sampler = config
    size = (args.size, args.size)
    return RenderTask(
        scene, size, (estimator,), sampler, spp, seed, args.backend, warmup_spp=args.spp[0]
    )


def one_render(executor, scene, peer, refs, who, what, spp, seed, args) -> dict:
    """One timed render (clrender configuration, a task on the executor, or Mitsuba sampler,
    in this process) and its errors against its renderer's reference."""
    if who == "mitsuba":
        image, row = peer.render(what, spp, seed)
        return scored_row(image, row, refs, who, f"mitsuba/{what}")
    task = clrender_task(scene, what, spp, seed, args)
    images, row = render_tasks(executor, [task])[0]
    return scored_row(images[what[0]], row, refs, who, pair_label(*what))


def scored_row(image, row: dict, refs: dict, who: str, label: str) -> dict:
    """The render's row with its errors against its renderer's reference, printed."""
    if who == "clrender":
        row["renderer"] = "clrender"
    row.update(image_errors(np.asarray(image, np.float64), *refs[who]))
    where = f"  on {row['worker']}" if "worker" in row else ""
    print(
        f"{row['spp']:4d} spp seed {row['seed']} {label:22s} MSE-noise "
        f"{row['mse_minus_ref_noise']:.3e}  wall {row['call_s']:6.2f} s  cpu {row['cpu_s']:6.2f} s"
        f"  load {row['load_1min']:.1f}{where}",
        flush=True,
    )
    return row


def run_study(executor, args, argv) -> None:
    """Every scene of --scenes; results.json keeps the entries of scenes not run again."""
    path = args.out / "results.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    results.setdefault("scenes", {})
    start = time.perf_counter()
    for scene in args.scenes:

        def save(entry, scene=scene):  # after each round: a killed run keeps what it has
            results["scenes"][scene] = entry
            write_json(path, results)

        previous = results["scenes"].get(scene)
        save(study_scene(executor, scene, args, argv, previous, save))
    results["seconds_last_run"] = time.perf_counter() - start
    write_json(path, results)
    efficiency_report.plot_all(results, args.out)
    (args.out / "report.md").write_text(efficiency_report.report(results) + "\n")
    print(f"done in {results['seconds_last_run']:.0f} s; wrote {args.out}/")


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
    if args.perf_ratio:
        run_perf_ratio(process_runtime(), args)
        return
    with executor_from_args(args) as executor:
        run_study(executor, args, argv)


if __name__ == "__main__":
    main()
