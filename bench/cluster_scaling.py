"""Speed of work on a Dask LocalCluster (clrender.cluster) against the same work in this process.

    python bench/cluster_scaling.py [--quick] [--repeats K] [--out FILE] [--cases NAME...]

Measured in one run, medians of K repeats after a warm-up (the cluster's workers build their
OpenCL programs and radiance sources once, as they would for a long study):
  analytic: a slice of the analytic study (bench/analytic_study.py: its estimators on SPPP draws
            at n = 1024), in this process (one core: NumPy and Qhull), then on 1 and 2 workers;
  render:   mitsuba-cbox 256 x 256, uniform/mc at 64 spp: clrender.pipeline.render in this
            process (the device uses both cores), then on 1 and 2 workers (each worker's device
            uses both cores too);
  overhead: per task, the round trip of trivial tasks through the scheduler (submit to
            result), and of a render split into many small tasks against few;
  placement: the render on a fresh cluster of 2 workers, its tasks placed by the scheduler
            (which starts every task where the shared job is) against dealt out to the workers
            in turn (DaskExecutor.spread_shared), alternated: wall time of the first render
            (workers setting up) and of the next (set up), and the tasks each worker ran.
Every cluster result is checked equal to the local one (bit for bit). Wall and process CPU time
(this process only: workers are other processes) are reported; the machine is shared, so the
load average is recorded beside. JSON goes to bench/results/cluster_scaling.json (git-ignored).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import analytic_study  # noqa: E402
from common import machine  # noqa: E402

from clrender.api import radiance_source, runtime_for  # noqa: E402
from clrender.cluster import DaskExecutor, RenderJob, render_on  # noqa: E402
from clrender.pipeline import RenderSettings, render  # noqa: E402
from clrender.sampling import make_sampler  # noqa: E402
from clrender.scene import load_scene  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "cluster_scaling.json"
CASES = ("analytic", "render", "overhead", "placement")


def timed(fn, repeats: int):
    """Median wall seconds of fn() over repeats after one warm-up call, and the last result."""
    result = fn()
    walls = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        walls.append(time.perf_counter() - start)
    return statistics.median(walls), result


def alternated(calls: dict, repeats: int) -> tuple[dict, dict]:
    """Median wall seconds of each call, run in rounds (one of each per round, after one
    warm-up round) so that the machine's load changes hit them alike; and their last results."""
    results = {name: call() for name, call in calls.items()}
    walls: dict = {name: [] for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            start = time.perf_counter()
            results[name] = call()
            walls[name].append(time.perf_counter() - start)
    return {name: statistics.median(w) for name, w in walls.items()}, results


def noop(item):
    return item


def analytic_case(executors: dict, repeats: int, n: int, runs: int) -> dict:
    """The analytic slice in this process and on each executor, alternated: seconds, speed-up
    over this process, and whether the numbers are the same."""
    calls = {"local": lambda: analytic_study.run_estimates(n, runs, (7, 2), None)}
    for name, executor in executors.items():
        calls[name] = lambda ex=executor: analytic_study.run_estimates(n, runs, (7, 2), ex)
    seconds, results = alternated(calls, repeats)
    local = results["local"][0]
    rows = {}
    for name, result in results.items():
        same = all(np.array_equal(result[0][k], local[k], equal_nan=True) for k in local)
        rows[name] = {
            "seconds": seconds[name],
            "speedup_vs_local": seconds["local"] / seconds[name],
            "identical": same,
        }
    return {"n": n, "runs": runs, "rows": rows}


def render_case(executors: dict, repeats: int, size: int, spp: int) -> dict:
    """The render in this process and on each executor, alternated: seconds, M paths/s, speed
    against this process, and whether the image is the same."""
    runtime = runtime_for(None)
    scene = load_scene("mitsuba-cbox")
    settings = RenderSettings(size, size, make_sampler("independent", spp), ["mc"], 1)
    source = radiance_source(runtime, scene, (size, size), 8)
    job = RenderJob.of(scene, settings, 8)
    calls = {"local": lambda: render(runtime, source, settings)}
    for name, executor in executors.items():
        calls[name] = lambda ex=executor: render_on(ex, job)
    seconds, results = alternated(calls, repeats)
    paths = size * size * spp
    rows = {}
    for name, result in results.items():
        rows[name] = {
            "seconds": seconds[name],
            "mpaths_per_s": paths / seconds[name] / 1e6,
            "speed_vs_local": seconds["local"] / seconds[name],
            "identical": bool(np.array_equal(result.image, results["local"].image)),
        }
    return {"size": size, "spp": spp, "rows": rows}


def overhead_case(executor: DaskExecutor, repeats: int, size: int, spp: int) -> dict:
    """Seconds per trivial task, and per extra task of a split render."""
    tasks = 200

    def trivial():
        for _ in executor.map(noop, list(range(tasks))):
            pass

    trivial_s, _ = timed(trivial, repeats)
    scene = load_scene("mitsuba-cbox")
    settings = RenderSettings(size, size, make_sampler("independent", spp), ["mc"], 1)
    job = RenderJob.of(scene, settings, 8)
    few, _ = timed(lambda: render_on(executor, job, tasks=2), repeats)
    many, result = timed(lambda: render_on(executor, job, tasks=64), repeats)
    return {
        "trivial_tasks": tasks,
        "seconds_per_trivial_task": trivial_s / tasks,
        "render_size": size,
        "render_spp": spp,
        "render_2_tasks_s": few,
        "render_64_tasks_s": many,
        "seconds_per_extra_render_task": (many - few) / 62,
    }


def placement_case(repeats: int, size: int, spp: int) -> dict:
    """The render on a fresh 2-worker cluster per run, placed by the scheduler or spread, in
    alternated rounds (the order reversed every other round): median wall seconds of the first
    render and of the second, the median over rounds of spread / scheduler for each, each run's
    tasks per worker (largest first), and whether every image equals the local render's."""
    runtime = runtime_for(None)
    scene = load_scene("mitsuba-cbox")
    settings = RenderSettings(size, size, make_sampler("independent", spp), ["mc"], 1)
    local = render(runtime, radiance_source(runtime, scene, (size, size), 8), settings).image
    runs: dict = {"scheduler": [], "spread": []}
    identical = True
    for round_index in range(repeats):
        names = list(runs) if round_index % 2 == 0 else list(reversed(runs))
        for name in names:
            job = RenderJob.of(scene, settings, 8)
            with DaskExecutor(workers=2) as executor:
                executor.spread_shared = name == "spread"
                walls, placements = [], []
                for _ in range(2):  # the first render sets the workers up, the second does not
                    start = time.perf_counter()
                    result = render_on(executor, job)
                    walls.append(time.perf_counter() - start)
                    placements.append(sorted(result.tasks_by_worker.values(), reverse=True))
                    identical = identical and bool(np.array_equal(result.image, local))
            runs[name].append({"wall_s": walls, "tasks_by_worker": placements})
    summary = {}
    for name, row in runs.items():
        summary[name] = {
            "first_render_s": statistics.median(run["wall_s"][0] for run in row),
            "second_render_s": statistics.median(run["wall_s"][1] for run in row),
            "runs": row,
        }
    for k, key in enumerate(
        ("first_render_spread_over_scheduler", "second_render_spread_over_scheduler")
    ):
        summary[key] = statistics.median(
            spread["wall_s"][k] / scheduler["wall_s"][k]
            for spread, scheduler in zip(runs["spread"], runs["scheduler"], strict=True)
        )
    return {"size": size, "spp": spp, "tasks": 8, "identical": identical, "rows": summary}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, one repeat")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument(
        "--cases",
        nargs="+",
        choices=CASES,
        default=list(CASES),
        help="which measurements to run (default: all)",
    )
    args = parser.parse_args(argv)
    repeats = 1 if args.quick else args.repeats
    n, runs = (64, 64) if args.quick else (1024, 1200)
    size, spp = (32, 4) if args.quick else (256, 64)
    results = {"command": " ".join(["python bench/cluster_scaling.py", *(argv or sys.argv[1:])])}
    results["machine_before"] = machine()
    cpu0 = time.process_time()
    if {"analytic", "render", "overhead"} & set(args.cases):
        with DaskExecutor(workers=1) as one, DaskExecutor(workers=2) as two:
            executors = {"1 worker": one, "2 workers": two}
            if "analytic" in args.cases:
                results["analytic"] = analytic_case(executors, repeats, n, runs)
                print(json.dumps(results["analytic"], indent=1), flush=True)
            if "render" in args.cases:
                results["render"] = render_case(executors, repeats, size, spp)
                print(json.dumps(results["render"], indent=1), flush=True)
            if "overhead" in args.cases:
                results["overhead"] = overhead_case(two, repeats, size // 2, spp // 4 or 1)
                print(json.dumps(results["overhead"], indent=1), flush=True)
    if "placement" in args.cases:
        results["placement"] = placement_case(max(repeats, 2), size, spp)
        print(json.dumps(results["placement"], indent=1), flush=True)
    results["this_process_cpu_s"] = time.process_time() - cpu0
    results["machine_after"] = machine()
    results["cpu_count"] = os.cpu_count()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
