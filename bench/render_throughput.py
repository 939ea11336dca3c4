"""Whole-render throughput of clrender, stage by stage, beside Mitsuba 3 in the same run.

Renders mitsuba-cbox (256 x 256 by default) with clrender through its Python front door, each
configuration (sampler/estimator) at each spp, and, when `mitsuba` is installed with its LLVM
backend (bench/mitsuba_peer.py), Mitsuba's own Cornell box at the same size and spp (its
independent sampler, default settings: Russian roulette from depth 5). Renders alternate
(clrender configurations, then Mitsuba, repeat after repeat), after one warm-up render of each
(kernels built, Mitsuba's JIT warm). Per render: wall time, CPU time of the process (PoCL's and
Dr.Jit's threads count as they run in it), paths = traced samples, and clrender's time per
stage (sample sets, tracing, Voronoi, read-back, host estimators and layers; RenderStats).

Printed and written as JSON (bench/results/throughput/results.json): per configuration and
spp, medians over repeats of wall and CPU paths/s, each stage's share of the render, the render
against its own tracing stage (render / tracing: the cost beyond the trace kernel), and the
ratios to Mitsuba measured in this run. The machine is shared: the load average is recorded
beside every render.

    python bench/render_throughput.py                         # 64 and 256 spp, 5 repeats
    python bench/render_throughput.py --spp 64 --repeats 3 --configs independent/mc sppp/vor_sn

A configuration may name the trace kernel after an @ (clrender.render's trace_kernel: auto by
default, megakernel or simd), to compare kernels in one run:

    python bench/render_throughput.py --configs independent/mc@megakernel independent/mc@simd

With --trees A B ..., compares source trees (worktrees or checkouts of clrender) in one run
instead: each repeat renders every configuration once (after a warm-up render of each) in a
new process per tree, with that tree's package and kernels (PYTHONPATH, CLRENDER_KERNELS_DIR),
the trees' order reversed every other repeat; per tree and configuration it reports medians of
wall and CPU time, and the median over repeats of each configuration's ratio to the first
configuration's render in the same process (e.g. vor_sn / mc_n), and of the render against its
tracing stage (a tree's own stage clock: before the stages were timed on the device's clock,
the tracing stage also held the main thread's wait for it). Mitsuba is not run.

    python bench/render_throughput.py --trees /work/main . --spp 256 --repeats 4 \
        --configs sppp/mc_n sppp/vor_sn
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import command_line, machine, write_json  # noqa: E402
from mitsuba_peer import MitsubaPeer  # noqa: E402

import clrender  # noqa: E402
from clrender.pipeline import DEVICE_STAGES as STAGES  # noqa: E402
from clrender.trace import TRACE_KERNEL_CHOICES  # noqa: E402

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "results" / "throughput"
DEFAULT_CONFIGS = ("independent/mc", "sobol/mc", "sppp/vor_sn")


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default="mitsuba-cbox")
    parser.add_argument("--size", type=int, default=256, help="image width = height")
    parser.add_argument("--spp", type=int, nargs="+", default=[64, 256])
    parser.add_argument(
        "--configs",
        nargs="+",
        default=list(DEFAULT_CONFIGS),
        metavar="S/E[@K]",
        help="sampler/estimator, optionally @trace kernel (auto, megakernel, simd)",
    )
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-mitsuba", action="store_true", help="clrender alone")
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT)
    parser.add_argument(
        "--trees", type=Path, nargs="+", metavar="DIR", help="compare these source trees"
    )
    args = parser.parse_args(argv)
    for config in args.configs:
        try:
            parse_config(config)
        except ValueError as err:
            parser.error(str(err))
    return args


def parse_config(config: str) -> tuple[str, str, str]:
    """(sampler, estimator, trace kernel) of "sampler/estimator[@kernel]"; ValueError in one
    line for another form."""
    pair, _, kernel = config.partition("@")
    sampler, slash, estimator = pair.partition("/")
    kernel = kernel or "auto"
    if not (sampler and slash and estimator) or kernel not in TRACE_KERNEL_CHOICES:
        raise ValueError(
            f"configuration {config!r}: expected sampler/estimator[@kernel] with kernel one "
            f"of {', '.join(TRACE_KERNEL_CHOICES)}"
        )
    return sampler, estimator, kernel


def clrender_render(scene, config: str, spp: int, size: int, seed: int) -> dict:
    """One timed clrender render: wall, CPU, paths and the stages."""
    sampler, estimator, kernel = parse_config(config)
    cpu = time.process_time()
    start = time.perf_counter()
    result = clrender.render(
        scene,
        spp=spp,
        sampler=sampler,
        estimator=estimator,
        resolution=size,
        seed=seed,
        trace_kernel=kernel,
    )
    call = time.perf_counter() - start
    stats = result.stats
    return {
        "renderer": "clrender",
        "config": config,
        "trace_kernel": result.trace_kernel,  # the one auto chose, or the one asked for
        "spp": spp,
        "seed": seed,
        "call_s": call,
        "wall_s": stats.wall_seconds,
        "run_s": stats.run_seconds,
        "cpu_s": time.process_time() - cpu,
        "paths": stats.traced_samples,
        "compile_s": stats.compile_seconds + stats.setup_compile_seconds,
        **{f"{stage}_s": stats.stage_seconds[stage] for stage in STAGES},
        "host_s": stats.host_seconds,
        "load_1min": os.getloadavg()[0],
    }


def mitsuba_render(peer: MitsubaPeer, spp: int, seed: int) -> dict:
    """One timed Mitsuba render (independent sampler, its default settings)."""
    _, row = peer.render("independent", spp, seed)
    row.update(renderer="mitsuba", config="mitsuba/independent")
    row["paths"] = peer.width * peer.height * row["spp_used"]
    return row


def summarise(rows: list[dict]) -> dict:
    """Medians over repeats: paths/s (wall, CPU), and for clrender each stage's share and the
    render against its tracing stage."""
    median = statistics.median
    paths = rows[0]["paths"]
    summary = {
        "repeats": len(rows),
        "wall_s": median(r["call_s"] for r in rows),
        "cpu_s": median(r["cpu_s"] for r in rows),
        "wall_paths_per_s": median(r["paths"] / r["call_s"] for r in rows),
        "cpu_paths_per_s": median(r["paths"] / r["cpu_s"] for r in rows),
        "paths": paths,
        "load_1min": median(r["load_1min"] for r in rows),
    }
    if rows[0]["renderer"] == "clrender":
        for key in ("tracing_s", "sample_sets_s", "voronoi_s", "moments_s", "readback_s"):
            summary[key] = median(r.get(key, 0.0) for r in rows)
        summary["host_s"] = median(r["host_s"] for r in rows)
        summary["render_over_tracing"] = median(r["call_s"] / r["tracing_s"] for r in rows)
        summary["untimed_s"] = median(
            r["call_s"] - sum(r[f"{stage}_s"] for stage in STAGES) - r["host_s"] for r in rows
        )
    return summary


def tree_renders(tree: Path, args, output: Path) -> list[dict]:
    """One repeat of every configuration (after a warm-up of each) in a new process that
    imports the tree's package and builds its kernels; its render rows."""
    tree = tree.resolve()
    script = tree / "bench" / "render_throughput.py"
    env = {**os.environ, "PYTHONPATH": str(tree), "CLRENDER_KERNELS_DIR": str(tree / "kernels")}
    command = [sys.executable, str(script), "--scene", args.scene, "--size", str(args.size)]
    command += ["--spp", *map(str, args.spp), "--configs", *args.configs]
    command += ["--repeats", "1", "--no-mitsuba", "--output", str(output)]
    subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL)
    return json.loads((output / "results.json").read_text())["renders"]


def compare_trees(args, argv) -> None:
    """--trees: the configurations rendered by each tree, alternating (see the docstring)."""
    rows: dict[str, list[dict]] = {str(tree): [] for tree in args.trees}
    with tempfile.TemporaryDirectory() as scratch:
        for repeat in range(args.repeats):
            order = args.trees if repeat % 2 == 0 else args.trees[::-1]
            for k, tree in enumerate(order):
                output = Path(scratch) / f"{repeat}-{k}"
                for row in tree_renders(tree, args, output):
                    rows[str(tree)].append({**row, "process": f"{repeat}-{k}"})
                print(f"repeat {repeat + 1}/{args.repeats}: {tree} done", flush=True)
    median = statistics.median
    summary: dict[str, dict] = {}
    for tree, tree_rows in rows.items():
        summary[tree] = {}
        for spp in args.spp:
            points = {}
            # each process's render of the first configuration
            first = {
                r["process"]: r
                for r in tree_rows
                if r["spp"] == spp and r["config"] == args.configs[0]
            }
            for config in args.configs:
                group = [r for r in tree_rows if r["spp"] == spp and r["config"] == config]
                point = {
                    "repeats": len(group),
                    "wall_s": median(r["call_s"] for r in group),
                    "cpu_s": median(r["cpu_s"] for r in group),
                    "voronoi_s": median(r["voronoi_s"] for r in group),
                    "tracing_s": median(r["tracing_s"] for r in group),
                    "render_over_tracing": median(r["call_s"] / r["tracing_s"] for r in group),
                    "load_1min": median(r["load_1min"] for r in group),
                    "wall_ratio_to_first": median(
                        r["call_s"] / first[r["process"]]["call_s"] for r in group
                    ),
                    "cpu_ratio_to_first": median(
                        r["cpu_s"] / first[r["process"]]["cpu_s"] for r in group
                    ),
                }
                points[config] = point
                print(
                    f"{tree}: {spp} spp {config}: wall {point['wall_s']:.2f} s, CPU "
                    f"{point['cpu_s']:.2f} s (Voronoi stage {point['voronoi_s']:.2f} s, render/"
                    f"tracing {point['render_over_tracing']:.3f}), / "
                    f"{args.configs[0]}: {point['wall_ratio_to_first']:.3f} wall, "
                    f"{point['cpu_ratio_to_first']:.3f} CPU, load {point['load_1min']:.1f}"
                )
            summary[tree][str(spp)] = points
    data = {
        "command": command_line("render_throughput.py", argv),
        "scene": args.scene,
        "size": args.size,
        "machine": machine(),
        "trees": [str(tree) for tree in args.trees],
        "summary": summary,
        "renders": rows,
    }
    write_json(args.output / "trees.json", data)
    print(f"wrote {args.output / 'trees.json'}")


def main(argv=None) -> None:
    args = parse_args(argv)
    if args.trees:
        compare_trees(args, argv)
        return
    scene = clrender.load_scene(args.scene)
    peer = None if args.no_mitsuba else MitsubaPeer(args.size, args.size, log=print)
    if peer is not None and not (peer.available and peer.status()["comparable_timings"]):
        print(f"mitsuba: not compared ({peer.status()})")
        peer = None
    rows: list[dict] = []
    for spp in args.spp:
        # Warm-up: kernels built and cached, Mitsuba's JIT compiled; not recorded
        for config in args.configs:
            clrender_render(scene, config, spp, args.size, seed=999)
        if peer is not None:
            mitsuba_render(peer, spp, seed=999)
        for repeat in range(args.repeats):
            for config in args.configs:
                rows.append(clrender_render(scene, config, spp, args.size, seed=repeat))
                print(f"{spp} spp {config}: {rows[-1]['call_s']:.3f} s", flush=True)
            if peer is not None:
                rows.append(mitsuba_render(peer, spp, seed=repeat))
                print(f"{spp} spp mitsuba: {rows[-1]['call_s']:.3f} s", flush=True)
    summary = {}
    for spp in args.spp:
        groups = {}
        for row in rows:
            if row["spp"] == spp:
                groups.setdefault(row["config"], []).append(row)
        points = {config: summarise(group) for config, group in groups.items()}
        mitsuba = points.get("mitsuba/independent")
        for config, point in points.items():
            if mitsuba is not None and config != "mitsuba/independent":
                point["wall_ratio_to_mitsuba"] = (
                    point["wall_paths_per_s"] / mitsuba["wall_paths_per_s"]
                )
                point["cpu_ratio_to_mitsuba"] = (
                    point["cpu_paths_per_s"] / mitsuba["cpu_paths_per_s"]
                )
        summary[str(spp)] = points
    data = {
        "command": command_line("render_throughput.py", argv),
        "scene": args.scene,
        "size": args.size,
        "machine": machine(),
        "mitsuba": None if peer is None else peer.status(),
        "summary": summary,
        "renders": rows,
    }
    write_json(args.output / "results.json", data)
    for spp, points in summary.items():
        for config, point in points.items():
            ratio = point.get("wall_ratio_to_mitsuba")
            extra = (
                ""
                if ratio is None
                else (f", {ratio:.2f}x Mitsuba wall, {point['cpu_ratio_to_mitsuba']:.2f}x CPU")
            )
            over = point.get("render_over_tracing")
            trace = "" if over is None else f", render/tracing {over:.2f}"
            print(
                f"{spp} spp {config}: {point['wall_paths_per_s'] / 1e6:.2f} M paths/s wall, "
                f"{point['cpu_paths_per_s'] / 1e6:.2f} M per CPU-s{trace}{extra}"
            )
    print(f"wrote {args.output / 'results.json'}")


if __name__ == "__main__":
    main()
