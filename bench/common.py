"""Helpers shared by the render benches: scene sources, timed renders, cached references,
image error metrics, machine load and report writing.

Where renders run: a study's renders are `RenderTask`s (plain data: scene name, size,
estimators, sampler, spp, seed, path settings), each rendered whole by `render_task` in this
process or on a worker of a Dask cluster (--workers / --scheduler: clrender.cluster), which
keeps its OpenCL runtime and radiance sources between tasks and sends back the images as NumPy
arrays with the render's row of timings. A task's time is taken where it runs: wall and CPU
time (time.process_time: PoCL's threads run in the process; a worker runs one task at a time)
of that render in that process. Workers render different configurations at once, so on a
cluster a render's wall time includes waiting for cores the other workers use; its CPU time is
the render's own work (plus the worker's small share of Dask's threads). Every row records the
worker and the load.

References: the mean of REFERENCE_PARTS independent renders (mc over REFERENCE_SAMPLER samples:
padded Owen-scrambled Sobol in every path dimension, the lowest-variance sampler that takes any
count; seeds REFERENCE_SEED + k, so the parts are independent scrambles, spp / REFERENCE_PARTS
samples each), so that the reference's own noise is measured rather than assumed: the per-pixel
variance of the mean is the spread of the parts divided by their number. Both maps are cached
as EXR under bench/results/references/ and reused when the scene, size, spp, depth, sampler and
parts match (the file name and its metadata).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from clrender import compare
from clrender.cluster import (
    DaskExecutor,
    LocalExecutor,
    RenderJob,
    make_executor,
    process_cache,
    render_on,
    worker_name,
)
from clrender.imageio import read_exr, srgb_encode, write_atomically, write_exr
from clrender.pipeline import RenderResult, RenderSettings, render
from clrender.provenance import kernels_fingerprint, scene_fingerprint
from clrender.radiance import PathTracerSource
from clrender.runtime import Runtime, create_runtime
from clrender.sampling import make_sampler
from clrender.scene import load_scene
from clrender.trace import PathTracer

Executor = LocalExecutor | DaskExecutor

RESULTS = Path(__file__).resolve().parent / "results"
REFERENCE_DIR = RESULTS / "references"
MAX_DEPTH = 8
REFERENCE_PARTS = 4
REFERENCE_SEED = 1000
REFERENCE_SAMPLER = "sobol"
# (estimator, sampler) pairs of the image benches: the paper's rnd/mc, the stratified baseline,
# then the SPPP family, the any-sampler Voronoi variants, and the image-level ones.
RENDER_PAIRS = [
    ("mc", "independent"),
    ("mc", "stratified"),
    ("mc_n", "sppp"),
    ("vor", "sppp"),
    ("vor_sn", "sppp"),
    ("fvor", "sppp"),
    ("cvor", "independent"),
    ("pvor", "independent"),
    ("ivor", "sppp"),
    ("ivor_sn", "sppp"),
]
VORONOI_ESTIMATORS = ("vor", "vor_sn", "fvor", "cvor", "pvor", "ivor", "ivor_sn")
# The paper's Figure 7 (256 spp, against a 4096 spp stratified reference).
PAPER_MSE = {"mc": 0.030, "vor": 0.015}


def pair_label(estimator: str, sampler: str) -> str:
    return f"{estimator}/{sampler}"


def make_tracer(runtime: Runtime, scene: str, max_depth: int = MAX_DEPTH) -> PathTracer:
    return PathTracer(runtime, load_scene(scene), max_depth=max_depth)


def make_source(runtime: Runtime, scene: str, width: int, height: int) -> PathTracerSource:
    return PathTracerSource(make_tracer(runtime, scene), width, height)


# ---------------------------------------------------------------------------------------------
# Renders


def has_backend_setting() -> bool:
    """Whether RenderSettings takes a voronoi_backend (the device cell areas)."""
    return "voronoi_backend" in {f.name for f in fields(RenderSettings)}


def default_backend() -> str | None:
    """The render's own default backend where it has one (None: the setting does not exist)."""
    return RenderSettings.voronoi_backend if has_backend_setting() else None


def render_settings(
    size: tuple[int, int],
    estimator: str,
    sampler: str,
    spp: int,
    seed: int,
    backend: str | None = None,
) -> RenderSettings:
    extra = {"voronoi_backend": backend} if backend and has_backend_setting() else {}
    return RenderSettings(size[0], size[1], make_sampler(sampler, spp), estimator, seed, **extra)


def timed_render(
    runtime: Runtime,
    source: PathTracerSource,
    estimator: str,
    sampler: str,
    spp: int,
    seed: int,
    backend: str | None = None,
) -> tuple[np.ndarray, dict]:
    """(image (H, W, 3) float64, timings and counters of the render): wall_s is the render's
    own wall time (RenderStats), call_s the whole call to the image in hand (as a peer renderer
    is timed), cpu_s the process's CPU time over the call (PoCL's threads run in-process)."""
    images, row = measured_render(runtime, source, (estimator,), sampler, spp, seed, backend)
    return images[estimator].astype(np.float64), row


def measured_render(
    runtime: Runtime,
    source: PathTracerSource,
    estimators: tuple[str, ...],
    sampler: str,
    spp: int,
    seed: int,
    backend: str | None = None,
) -> tuple[dict[str, np.ndarray], dict]:
    """({estimator: image (H, W, 3) float32}, the row of timed_render) of one render of one
    or more estimators (several: one trace, one film each); the row's counters and cells are
    the first estimator's."""
    wanted = estimators[0] if len(estimators) == 1 else list(estimators)
    settings = render_settings((source.width, source.height), wanted, sampler, spp, seed, backend)
    cpu = time.process_time()
    start = time.perf_counter()
    result: RenderResult = render(runtime, source, settings)
    images = {name: film.image() for name, film in result.films.items()}
    call = time.perf_counter() - start
    stats = result.stats
    row = {
        "estimator": estimators[0],
        "sampler": sampler,
        "spp": spp,
        "seed": seed,
        "wall_s": stats.wall_seconds,
        "run_s": stats.run_seconds,
        "call_s": call,
        "device_s": stats.device_seconds,
        "host_s": stats.host_seconds,
        "tracing_s": stats.stage_seconds["tracing"],
        "compile_s": stats.compile_seconds,
        "cpu_s": time.process_time() - cpu,
        "load_1min": os.getloadavg()[0],
        "paths": stats.traced_samples,
        "rays": stats.rays,
        "redrawn_pixels": stats.redrawn_pixels,
        "unresolved_pixels": stats.unresolved_pixels,
        "nonfinite_samples": stats.nonfinite_samples,
        "flagged_pixels": result.film.flagged_count,
        "cells": cell_backend(settings),
    }
    return images, row


# ---------------------------------------------------------------------------------------------
# Renders as tasks (here or on a cluster)


@dataclass(frozen=True)
class RenderTask:
    """One whole render as plain data: what a worker needs to render it and nothing it built.
    estimators: one, or several sharing one trace; defines: kernel build defines of the path
    tracer (name, value) pairs, as PathTracer's profile_defines."""

    scene: str
    size: tuple[int, int]
    estimators: tuple[str, ...]
    sampler: str
    spp: int
    seed: int
    backend: str | None = None
    max_depth: int = MAX_DEPTH
    russian_roulette: bool = False
    defines: tuple[tuple[str, int], ...] = ()
    device: str | None = None
    warmup_spp: int = 4  # the warm-up render's spp (at most the task's; the kernels are the same)


# An untimed render before the first timed one of each (source, estimators, sampler) in a
# process: kernel builds and first launches are not timed, wherever the task runs.
WARMUP_SEED = 999


def process_runtime(device: str | None = None) -> Runtime:
    """This process's OpenCL runtime for a device request, made once (its programs are built
    once per context): the study's own when local, each worker's own on a cluster."""
    runtimes = process_cache("bench.runtimes")
    if device not in runtimes:
        runtimes[device] = create_runtime(device)
    return runtimes[device]


def source_key(task: RenderTask) -> tuple:
    """What a task's radiance source depends on (tasks that share it share its kernels)."""
    return (task.scene, task.size, task.max_depth, task.russian_roulette, task.defines, task.device)


def task_source(task: RenderTask) -> PathTracerSource:
    """The task's radiance source, made once per process and kept for the next task."""
    sources = process_cache("bench.sources")
    key = source_key(task)
    if key not in sources:
        tracer = PathTracer(
            process_runtime(task.device),
            load_scene(task.scene),
            max_depth=task.max_depth,
            russian_roulette=task.russian_roulette,
            profile_defines=dict(task.defines) or None,
        )
        sources[key] = PathTracerSource(tracer, *task.size)
    return sources[key]


def render_task(task: RenderTask) -> tuple[dict[str, np.ndarray], dict]:
    """({estimator: image (H, W, 3) float32}, row) of one task, timed where it runs (after an
    untimed warm-up the first time this process meets its source, estimators and sampler);
    the row names the worker (or "this process")."""
    runtime = process_runtime(task.device)
    source = task_source(task)
    args = (task.estimators, task.sampler)
    warmed = process_cache("bench.warmed")
    key = (source_key(task), *args, task.backend)
    if key not in warmed:
        warmup_spp = min(task.warmup_spp, task.spp)
        measured_render(runtime, source, *args, warmup_spp, WARMUP_SEED, task.backend)
        warmed[key] = True
    images, row = measured_render(runtime, source, *args, task.spp, task.seed, task.backend)
    row["worker"] = worker_name()
    return images, row


def render_tasks(executor: Executor, tasks: list[RenderTask]) -> list[tuple[dict, dict]]:
    """render_task of every task on the executor, in the order of `tasks`; each row also
    records how many workers the executor had (1: this process)."""
    results: list = [None] * len(tasks)
    workers = executor.workers
    for index, (images, row) in executor.map(render_task, tasks):
        row["workers"] = workers
        results[index] = images, row
    return results


def cell_backend(settings: RenderSettings) -> str:
    """Where the render's Voronoi cells came from: "device", "qhull" (host) or "none" (mc)."""
    if settings.estimator.cells == "none":
        return "none"
    return "device" if getattr(settings, "device_cells", False) else "qhull"


def executor_record(executor: Executor, args) -> dict:
    """Where a render study ran and which clock its efficiency uses: wall time in this
    process; CPU time on a cluster (its renders share cores with the other workers')."""
    on_cluster = isinstance(executor, DaskExecutor)
    return {
        "where": executor_label(args),
        "workers": executor.workers,
        "clock": "cpu" if on_cluster else "wall",
        "timed": "on the worker that rendered it (wall and CPU time of that render in that "
        "worker process, one task at a time per worker)"
        if on_cluster
        else "in this process",
    }


# ---------------------------------------------------------------------------------------------
# References


def reference_path(scene: str, size: tuple[int, int], spp: int) -> Path:
    name = (
        f"{scene}_{size[0]}x{size[1]}_{spp}spp_d{MAX_DEPTH}_{REFERENCE_SAMPLER}_p{REFERENCE_PARTS}"
    )
    return REFERENCE_DIR / f"{name}.exr"


def reference_fingerprint(scene: str) -> str:
    """What a scene's reference depends on besides the settings in its file name: the scene as
    the device gets it (camera, materials, every shape and emitter, whatever file it came from)
    and the kernel sources that trace it (clrender.provenance). A cached reference whose
    fingerprint differs is rendered anew (an edited scene or a changed kernel)."""
    return f"{scene_fingerprint(load_scene(scene))}-{kernels_fingerprint()}"


def reference(
    runtime: Runtime,
    scene: str,
    size: tuple[int, int],
    spp: int,
    log=print,
    executor: Executor | None = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """(mean image, per-pixel variance of that mean, info): cached, else rendered (on the
    executor when one is given: render_reference)."""
    path = reference_path(scene, size, spp)
    var_path = path.with_name(path.stem + "_var.exr")
    want = {
        "scene": scene,
        "spp": spp,
        "parts": REFERENCE_PARTS,
        "max_depth": MAX_DEPTH,
        "sampler": REFERENCE_SAMPLER,
        "fingerprint": reference_fingerprint(scene),
    }
    if path.exists() and var_path.exists():
        image, meta = read_exr(path)
        if all(str(meta.get(k)) == str(v) for k, v in want.items()):
            log(f"reference: cached {path.name}")
            return (
                image.astype(np.float64),
                read_exr(var_path)[0].astype(np.float64),
                {**want, "path": str(path), "cached": True, "wall_s": float(meta["wall_s"])},
            )
        log(f"reference: {path.name} is of other settings, another scene or other kernels")
    image, variance, wall = render_reference(runtime, scene, size, spp, log, executor)
    REFERENCE_DIR.mkdir(parents=True, exist_ok=True)
    write_exr(path, image, {**want, "wall_s": wall, "estimator": "mc"})
    write_exr(var_path, variance, want)
    return image, variance, {**want, "path": str(path), "cached": False, "wall_s": wall}


def render_reference(
    runtime: Runtime,
    scene: str,
    size: tuple[int, int],
    spp: int,
    log=print,
    executor: Executor | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Mean of REFERENCE_PARTS mc renders over REFERENCE_SAMPLER and the variance of that mean,
    and the wall seconds it took. On a Dask executor each part is split over every worker by
    pixel ranges (clrender.cluster.render_on), bit-identical to the local render, so a
    reference cached by either is the other's; its time is the client's wall time."""
    part_spp = spp // REFERENCE_PARTS
    on_cluster = isinstance(executor, DaskExecutor)
    if on_cluster:
        settings = render_settings(size, "mc", REFERENCE_SAMPLER, part_spp, 0)
        job = RenderJob.of(load_scene(scene), settings, MAX_DEPTH)
    else:
        source = make_source(runtime, scene, *size)
    start = time.perf_counter()
    parts = []
    for k in range(REFERENCE_PARTS):
        seed = REFERENCE_SEED + k
        if on_cluster:
            part_job = dataclasses.replace(job, seed=seed)
            image = render_on(executor, part_job).film.image().astype(np.float64)
        else:
            image = timed_render(runtime, source, "mc", REFERENCE_SAMPLER, part_spp, seed)[0]
        parts.append(image)
        log(
            f"reference {scene} {size[0]}x{size[1]}: part {k + 1}/{REFERENCE_PARTS} "
            f"({part_spp} spp) done, {time.perf_counter() - start:.0f} s"
        )
    stack = np.stack(parts)
    variance = stack.var(axis=0, ddof=1) / REFERENCE_PARTS
    return stack.mean(axis=0), variance, time.perf_counter() - start


# ---------------------------------------------------------------------------------------------
# Metrics


def image_errors(image: np.ndarray, ref: np.ndarray, ref_variance: np.ndarray) -> dict:
    """Whole-image errors, each a mean over pixels and RGB channels:
    mse (linear radiance), mse_minus_ref_noise (mse less the reference's own variance, an
    unbiased estimate of the error against the true image), mse_clamped (both images clamped
    to [0, 1]), mse_srgb (both sRGB-encoded after clamping, display values in [0, 1]) and
    top_share (the share of the squared error in the worst 0.1 % of pixel channels), and
    bright_share (its share in the pixels brighter than display white, reference RGB mean > 1:
    the light and pixels its outline crosses) with bright_fraction (how many pixels those are)."""
    # MSE and the reference noise as the renderer reports them (clrender.compare)
    measured = compare.image_errors(image, ref, float(ref_variance.mean()))
    sq = (image - ref) ** 2
    flat = np.sort(sq.ravel())[::-1]
    top = max(1, len(flat) // 1000)
    total = max(float(flat.sum()), 1e-300)
    bright = ref.mean(axis=-1) > 1.0
    return {
        "mse": measured.mse,
        "ref_noise": measured.reference_noise,
        "mse_minus_ref_noise": measured.mse_minus_noise,
        "mse_clamped": float(((np.clip(image, 0, 1) - np.clip(ref, 0, 1)) ** 2).mean()),
        "mse_srgb": float(((srgb_encode(image) - srgb_encode(ref)) ** 2).mean()),
        "top_share": float(flat[:top].sum() / total),
        "bright_share": float(sq[bright].sum() / total),
        "bright_fraction": float(bright.mean()),
    }


# ---------------------------------------------------------------------------------------------
# Machine and outputs


def positive_int(text: str) -> int:
    """argparse type of options that count work per task: a positive integer."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def add_executor_options(parser) -> None:
    """--workers / --scheduler: where a study's tasks run (clrender.cluster; default here)."""
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="run the tasks on a Dask LocalCluster of N processes (same numbers as locally)",
    )
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run the tasks on the existing Dask cluster at ADDRESS",
    )


def executor_from_args(args):
    """The executor --workers / --scheduler name: local (this process) when neither is given."""
    return make_executor(args.workers, args.scheduler)


def executor_label(args) -> str:
    """Where --workers / --scheduler ran a study's tasks, for its report and JSON."""
    if args.scheduler is not None:
        return f"Dask cluster at {args.scheduler}"
    if args.workers is not None:
        return f"Dask LocalCluster of {args.workers} worker processes"
    return "this process"


def thread_seconds() -> dict[str, float]:
    """CPU seconds each thread of this process has run (Linux; empty elsewhere)."""
    seconds = {}
    tasks = Path("/proc/self/task")
    for task in tasks.iterdir() if tasks.is_dir() else ():
        try:
            seconds[task.name] = int((task / "schedstat").read_text().split()[0]) * 1e-9
        except (OSError, ValueError, IndexError):
            continue
    return seconds


def machine() -> dict:
    """Load average, CPU count and `uptime` line: the machine is shared."""
    try:
        uptime = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        uptime = ""
    return {"load_1_5_15": list(os.getloadavg()), "cpus": os.cpu_count(), "uptime": uptime}


def write_json(path: Path, data: dict) -> None:
    """Write data as JSON atomically: a study killed mid-write keeps its previous file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data, indent=1, default=float)
    write_atomically(path, lambda temp: temp.write_text(text))


def markdown_table(header: list[str], rows: list[list]) -> str:
    def cell(v):
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def command_line(script: str, argv) -> str:
    args = sys.argv[1:] if argv is None else list(argv)
    return f"python bench/{script} {' '.join(args)}".strip()
