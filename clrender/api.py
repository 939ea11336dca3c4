"""The Python front door: load a scene, render it, get the image as a NumPy array.

    import clrender

    scene = clrender.load_scene("cornell-box")
    result = clrender.render(scene, spp=64, estimator="vor_sn", resolution=64)
    result.image  # (64, 64, 3) float32 linear RGB, row 0 at the top
    result.stats.wall_seconds

    both = clrender.render(scene, spp=64, estimators=["mc_n", "vor_sn"], resolution=64)
    both.images["mc_n"], both.images["vor_sn"]  # one trace, one image per estimator

The command line (`python -m clrender render`) goes through the same functions.
"""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from clrender import pipeline
from clrender.analytic import (
    DEFAULT_RESOLUTION,
    AnalyticSource,
    analytic_image,
    is_analytic_scene,
)
from clrender.errors import ParameterError
from clrender.estimators import Estimator, EstimatorWarning, check_compatible, pairing_advice
from clrender.outputs import render_labels
from clrender.pipeline import (
    DEFAULT_TILE_SAMPLES,
    ProgressCallback,
    RenderResult,
    RenderSettings,
)
from clrender.provenance import local_fingerprints, provenance_warning, reported
from clrender.radiance import PathTracerSource, RadianceSource
from clrender.runtime import Runtime, create_runtime, thread_build_seconds
from clrender.sampling import make_sampler, sampler_kind
from clrender.scene import Scene
from clrender.scene import load_scene as load_scene_file
from clrender.trace import DEFAULT_MAX_DEPTH, PathTracer, check_max_depth, check_trace_kernel
from clrender.trace import image_size as scene_image_size


def default_estimator(sampler: str) -> str:
    """The estimator a sampler gets when none is named: vor_sn over the SPPP samplers (the
    paper's method, self-normalised), mc over every other."""
    return "vor_sn" if sampler_kind(sampler).is_sppp else "mc"


Resolution = int | tuple[int, int] | None


def load_scene(name_or_path: str | Path) -> Scene | str:
    """A shipped scene by name (cornell-box, cornell-box-glossy, mitsuba-cbox, furnace) or a
    scene file (.toml), validated; an `analytic[:KIND]` name is returned as it is (rendered as
    an image of known pixel integrals). SceneError (one line, naming the file and field) on a
    bad scene."""
    if isinstance(name_or_path, str) and is_analytic_scene(name_or_path):
        return name_or_path
    if not isinstance(name_or_path, str | Path):
        raise ParameterError(
            f"load_scene takes a scene name or a path, got {type(name_or_path).__name__} "
            f"{name_or_path!r}"
        )
    return load_scene_file(name_or_path)


def render(
    scene: Scene | str | Path,
    *,
    spp: int = 64,
    sampler: str = "sppp",
    estimator: str | Estimator | None = None,
    estimators: Sequence[str | Estimator] | None = None,
    resolution: Resolution = None,
    seed: int = 0,
    device: str | None = None,
    max_depth: int = DEFAULT_MAX_DEPTH,
    russian_roulette: bool = False,
    trace_kernel: str = "auto",
    tile_samples: int = DEFAULT_TILE_SAMPLES,
    overlap: bool = True,
    voronoi_backend: str = "device",
    progress: ProgressCallback | bool | None = None,
    executor=None,
) -> RenderResult:
    """Render a scene (a loaded Scene, a scene name or file, or `analytic[:KIND]`).

    spp: samples per pixel (the SPPP intensity n); sampler: a name of clrender.sampling.SAMPLERS;
    estimator: a name of clrender.estimators.ESTIMATORS (default vor_sn with sppp, mc
    otherwise), or estimators: a list of names, every one estimated from the same traced
    samples (`.images[name]`, one image each; see clrender.pipeline for redrawn pixels);
    resolution: None for the scene's own size, a width N (the scene's aspect ratio) or (width,
    height); device: an OpenCL device's index, whole name or a part of its description no
    other device shares (default PYOPENCL_CTX, else the first device); max_depth: scattering
    vertices per path; russian_roulette: end paths at random from their second vertex on
    (pbrt-v4's rule, unbiased; off by default, as in the paper; refused for analytic images,
    which have no paths); trace_kernel: "auto" (the simd kernel on a CPU device for a scene
    without triangles, BVH or emitters other than quads, the megakernel otherwise:
    clrender.trace.choose_trace_kernel), "megakernel" or "simd": the same image to the bit, at
    different speeds (clrender.trace.PathTracer; `.trace_kernel` says which ran); progress: a
    callable
    progress(done_pixels, total_pixels), called after each tile (each task on a cluster), or
    True for a progress bar (tqdm's: on a terminal or in Jupyter), None or False for none;
    overlap: True or False; executor: a
    clrender.cluster.DaskExecutor (made once, reused across renders) renders on its Dask
    cluster, bit-identical to the local render (default: this process).
    Returns a RenderResult: `.image` (H, W, 3) float32 linear RGB of the (first) estimator,
    `.images`, `.layers` (per-pixel sample counts, redraws, variance), `.stats` (with times per
    stage and per estimator), `.settings`, `.max_depth` and `.russian_roulette` (None for an
    analytic image). Bad arguments raise ParameterError (a ClrenderError)
    with a one-line message; a poor estimator/sampler pair warns (EstimatorWarning).
    One render at a time per process and device: renders share the device's runtime (its
    compiled programs), so calls from several threads must be serialised by the caller.
    """
    spp = check_sampler_name(sampler, spp)
    if not isinstance(overlap, bool):
        raise ParameterError(f"overlap must be True or False, got {overlap!r}")
    check_progress(progress)
    entries = estimator_entries(estimator, estimators, sampler)
    config = make_sampler(sampler, spp)
    if isinstance(scene, str | Path):
        scene = load_scene(scene)
    elif not isinstance(scene, Scene):
        raise ParameterError(
            "render takes a Scene (clrender.load_scene), a scene name or a path, got "
            f"{type(scene).__name__} {scene!r}"
        )
    if isinstance(scene, str):  # an analytic image's name: known, or a ParameterError
        analytic_image(scene, 1, 1)
    check_russian_roulette(russian_roulette, scene)
    check_max_depth(max_depth)  # an analytic image has no paths, but a wrong value is wrong
    check_trace_kernel(trace_kernel)
    check_executor(executor)
    for entry in entries:  # once every argument is known good: advice, not an error
        advice = pairing_advice(entry, sampler, spp)
        if advice:
            warnings.warn(advice, EstimatorWarning, stacklevel=2)
    if executor is None:
        runtime = runtime_for(device)
        built = thread_build_seconds()
        source = radiance_source(
            runtime, scene, resolution, max_depth, russian_roulette, trace_kernel
        )
        setup_compile = thread_build_seconds() - built
        width, height = source.width, source.height
    else:  # the workers choose the device and build the source: none is needed here
        width, height = image_size(scene, resolution)
    settings = RenderSettings(
        width,
        height,
        config,
        entries,
        seed,
        tile_samples,
        overlap,
        voronoi_backend,
    )
    bar = None
    if progress is True:
        from clrender.progress import ProgressBar

        label = scene if isinstance(scene, str) else scene.name
        progress = bar = ProgressBar(f"{label} {settings.width}x{settings.height}")
    try:
        if executor is None:
            result = pipeline.render(runtime, source, settings, progress or None)
            result.stats.setup_compile_seconds = setup_compile
        else:  # its workers' source builds (clrender.cluster), not this process's
            from clrender.cluster import RenderJob, render_on

            path_depth = 0 if isinstance(scene, str) else max_depth
            job = RenderJob.of(scene, settings, path_depth, russian_roulette, device, trace_kernel)
            result = render_on(executor, job, progress or None)
    finally:
        if bar is not None:
            bar.close()
    # the device(s), precision, kernels and code that rendered it: a cluster's workers', not
    # this process's (warned of when its kernels or code differ from theirs)
    result.labels = render_labels(
        analytic_image(scene, 1, 1).name if isinstance(scene, str) else scene.name,
        None if isinstance(scene, str) else scene,
        result.max_depth,
        result.russian_roulette,
        result,
    )
    if result.stats.interrupted:  # Ctrl-C stops the caller's script too, with the pixels
        raise RenderInterrupted(result)
    warning = provenance_warning(reported(result), local_fingerprints())
    if warning is not None:
        warnings.warn(warning, stacklevel=2)
    return result


def estimator_entries(
    estimator: str | Estimator | None,
    estimators: Sequence[str | Estimator] | None,
    sampler: str,
) -> list[Estimator]:
    """The registry entries of `estimator` or `estimators` (not both), each checked against
    the sampler; the sampler's default estimator when neither is given."""
    if estimators is None:
        return [check_compatible(estimator or default_estimator(sampler), sampler)]
    if estimator is not None:
        raise ParameterError("give estimator or estimators, not both")
    if isinstance(estimators, str | Estimator) or not isinstance(estimators, Sequence):
        raise ParameterError(
            f"estimators takes a list of names such as ['mc', 'vor_sn'], got {estimators!r}"
        )
    if not estimators:
        raise ParameterError("estimators is empty: name at least one")
    return [check_compatible(name, sampler) for name in estimators]


def check_sampler_name(sampler: str, spp: int) -> int:
    """spp (a Python or NumPy integer, returned as int) and the sampler's name (checked before
    the estimator, as on the command line)."""
    if isinstance(spp, bool) or not isinstance(spp, int | np.integer) or spp <= 0:
        raise ParameterError(f"spp must be a positive integer, got {spp!r}")
    sampler_kind(sampler)
    return int(spp)


def check_progress(progress: object) -> None:
    """progress is a callable, True (a progress bar), False or None, checked before any work."""
    if progress is None or isinstance(progress, bool) or callable(progress):
        return
    raise ParameterError(
        "progress must be a callable progress(done_pixels, total_pixels), True for a progress "
        f"bar, or None, got {type(progress).__name__} {progress!r}"
    )


def runtime_for(device: str | None) -> Runtime:
    """One OpenCL runtime per device request and process (its programs are built once; not
    for concurrent use from several threads). The default device is PYOPENCL_CTX's as it is
    now: a changed variable gets the runtime of the device it names."""
    return _runtime_for(device, os.environ.get("PYOPENCL_CTX", "").strip())


@functools.cache
def _runtime_for(device: str | None, pyopencl_ctx: str) -> Runtime:
    return create_runtime(device)


class RenderInterrupted(KeyboardInterrupt):
    """clrender.render was interrupted (Ctrl-C): `.result` is the RenderResult of the pixels
    finished (stats.interrupted set; `.result.save(path)` writes them with partial=1). A
    KeyboardInterrupt, so a script stops as it would anywhere else."""

    def __init__(self, result):
        film = result.film
        super().__init__(
            f"render interrupted: {film.rendered_count} of {film.pixel_count} pixels finished "
            "(the exception's .result holds them)"
        )
        self.result = result

    def __reduce__(self):  # pickled with its result (another process, a Dask task)
        return RenderInterrupted, (self.result,)


def check_executor(executor: object) -> None:
    """ParameterError unless executor is None or a clrender.cluster executor."""
    from clrender.cluster import DaskExecutor, LocalExecutor

    if executor is not None and not isinstance(executor, LocalExecutor | DaskExecutor):
        raise ParameterError(
            "executor must be None, a clrender.cluster.DaskExecutor or a LocalExecutor, got "
            f"{type(executor).__name__} {executor!r}"
        )


def check_russian_roulette(russian_roulette: object, scene: Scene | str) -> None:
    """russian_roulette is a bool, and True only for a scene with paths (not an analytic
    image)."""
    if not isinstance(russian_roulette, bool):
        raise ParameterError(f"russian_roulette must be True or False, got {russian_roulette!r}")
    if russian_roulette and isinstance(scene, str):
        raise ParameterError(
            f"Russian roulette needs a path-traced scene: {scene} is an analytic image "
            "without paths"
        )


def radiance_source(
    runtime: Runtime,
    scene: Scene | str,
    resolution: Resolution,
    max_depth: int,
    russian_roulette: bool = False,
    trace_kernel: str = "auto",
) -> RadianceSource:
    """The path tracer of a scene (or the analytic image of an `analytic[:KIND]` name) at the
    requested resolution; russian_roulette and trace_kernel (paths only) as
    clrender.trace.PathTracer's."""
    check_russian_roulette(russian_roulette, scene)
    check_trace_kernel(trace_kernel)
    width, height = image_size(scene, resolution)
    if isinstance(scene, str):
        return AnalyticSource.for_scene(scene, runtime.queue, width, height)
    tracer = PathTracer(
        runtime,
        scene,
        max_depth=max_depth,
        russian_roulette=russian_roulette,
        trace_kernel=trace_kernel,
    )
    return PathTracerSource(tracer, width, height)


def image_size(scene: Scene | str, resolution: Resolution) -> tuple[int, int]:
    """(width, height) of the image radiance_source renders for the scene (or `analytic[:KIND]`
    name) at the requested resolution, without a device: what a client of a cluster needs."""
    width, height = _resolution(resolution)
    if isinstance(scene, str):
        if width is None:
            return DEFAULT_RESOLUTION
        return width, width if height is None else height
    return scene_image_size(scene, width, height)


def _resolution(resolution: Resolution) -> tuple[int | None, int | None]:
    if resolution is None:
        return None, None
    if isinstance(resolution, int | np.integer) and not isinstance(resolution, bool):
        sizes = (resolution,)
    elif isinstance(resolution, tuple) and len(resolution) == 2:
        sizes = resolution
    else:
        sizes = ()
    whole = (int, np.integer)
    if not sizes or any(isinstance(v, bool) or not isinstance(v, whole) or v <= 0 for v in sizes):
        raise ParameterError(
            f"resolution must be None, a width N or (width, height) of positive integers, "
            f"got {resolution!r}"
        )
    return (int(sizes[0]), int(sizes[1])) if len(sizes) == 2 else (int(sizes[0]), None)
