"""Helpers shared by the render benches: scene sources, timed renders, cached references,
image error metrics, machine load and report writing.

References: the mean of REFERENCE_PARTS independent renders (mc over REFERENCE_SAMPLER samples:
padded Owen-scrambled Sobol in every path dimension, the lowest-variance sampler that takes any
count; seeds REFERENCE_SEED + k, so the parts are independent scrambles, spp / REFERENCE_PARTS
samples each), so that the reference's own noise is measured rather than assumed: the per-pixel
variance of the mean is the spread of the parts divided by their number. Both maps are cached
as EXR under bench/results/references/ and reused when the scene, size, spp, depth, sampler and
parts match (the file name and its metadata).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

from clrender import compare
from clrender.cluster import make_executor
from clrender.imageio import read_exr, srgb_encode, write_atomically, write_exr
from clrender.pipeline import RenderResult, RenderSettings, render
from clrender.radiance import PathTracerSource
from clrender.runtime import Runtime
from clrender.sampling import make_sampler
from clrender.scene import load_scene
from clrender.trace import PathTracer

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
    settings = render_settings(
        (source.width, source.height), estimator, sampler, spp, seed, backend
    )
    cpu = time.process_time()
    start = time.perf_counter()
    result: RenderResult = render(runtime, source, settings)
    image = result.film.image().astype(np.float64)
    call = time.perf_counter() - start
    stats = result.stats
    row = {
        "estimator": estimator,
        "sampler": sampler,
        "spp": spp,
        "seed": seed,
        "wall_s": stats.wall_seconds,
        "call_s": call,
        "device_s": stats.device_seconds,
        "host_s": stats.host_seconds,
        "cpu_s": time.process_time() - cpu,
        "load_1min": os.getloadavg()[0],
        "redrawn_pixels": stats.redrawn_pixels,
        "unresolved_pixels": stats.unresolved_pixels,
        "flagged_pixels": result.film.flagged_count,
        "cells": cell_backend(settings),
    }
    return image, row


def cell_backend(settings: RenderSettings) -> str:
    """Where the render's Voronoi cells came from: "device", "qhull" (host) or "none" (mc)."""
    if settings.estimator.cells == "none":
        return "none"
    return "device" if getattr(settings, "device_cells", False) else "qhull"


# ---------------------------------------------------------------------------------------------
# References


def reference_path(scene: str, size: tuple[int, int], spp: int) -> Path:
    name = (
        f"{scene}_{size[0]}x{size[1]}_{spp}spp_d{MAX_DEPTH}_{REFERENCE_SAMPLER}_p{REFERENCE_PARTS}"
    )
    return REFERENCE_DIR / f"{name}.exr"


def reference(
    runtime: Runtime, scene: str, size: tuple[int, int], spp: int, log=print
) -> tuple[np.ndarray, np.ndarray, dict]:
    """(mean image, per-pixel variance of that mean, info): cached, else rendered."""
    path = reference_path(scene, size, spp)
    var_path = path.with_name(path.stem + "_var.exr")
    want = {
        "scene": scene,
        "spp": spp,
        "parts": REFERENCE_PARTS,
        "max_depth": MAX_DEPTH,
        "sampler": REFERENCE_SAMPLER,
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
    image, variance, wall = render_reference(runtime, scene, size, spp, log)
    REFERENCE_DIR.mkdir(parents=True, exist_ok=True)
    write_exr(path, image, {**want, "wall_s": wall, "estimator": "mc"})
    write_exr(var_path, variance, want)
    return image, variance, {**want, "path": str(path), "cached": False, "wall_s": wall}


def render_reference(
    runtime: Runtime, scene: str, size: tuple[int, int], spp: int, log=print
) -> tuple[np.ndarray, np.ndarray, float]:
    """Mean of REFERENCE_PARTS mc renders over REFERENCE_SAMPLER and the variance of that mean."""
    part_spp = spp // REFERENCE_PARTS
    source = make_source(runtime, scene, *size)
    start = time.perf_counter()
    parts = []
    for k in range(REFERENCE_PARTS):
        parts.append(
            timed_render(runtime, source, "mc", REFERENCE_SAMPLER, part_spp, REFERENCE_SEED + k)[0]
        )
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
