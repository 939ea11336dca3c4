"""What a render reports: the EXR metadata, the closing summary and its JSON form."""

from __future__ import annotations

import math
from dataclasses import dataclass

from clrender import __version__
from clrender.estimators.variance import variance_is_unbiased
from clrender.pipeline import DEVICE_STAGES, RenderResult

# The per-pixel layers written beside RGB in every EXR (clrender.film.PixelLayers), with
# "flagged" from the estimator's film.
LAYER_NAMES = ("samples", "redraws", "flagged", "mc_variance")


@dataclass(frozen=True)
class RenderLabels:
    """Descriptions the pipeline itself does not know."""

    scene: str
    device: str | None  # RenderResult.device: None for a cluster render no task of which finished
    max_depth: int | None  # None for sources without paths (analytic images)
    russian_roulette: bool | None = None  # likewise None without paths
    # Provenance (clrender.provenance), None where not known: the scene file and the scene as
    # the device got it (none for analytic images), the kernel sources, the precision of the
    # device's Voronoi cells and sums ("mixed" with cl_khr_fp64, else "single"), and
    # clrender's Python code
    scene_file: str | None = None
    scene_sha256: str | None = None
    kernels_sha256: str | None = None
    device_precision: str | None = None
    code_sha256: str | None = None


def render_metadata(
    result: RenderResult,
    labels: RenderLabels,
    estimator: str | None = None,
    errors: dict | None = None,
) -> dict[str, object]:
    """EXR header attributes describing the render and one of its estimators' images (the
    first by default); errors: the image's error against a reference (clrender.compare's
    ImageErrors.as_dict() with the reference's name), stored with an `error_` prefix. See
    clrender.imageio for the attribute types."""
    settings, stats = result.settings, result.stats
    name = estimator or settings.estimator.name
    film = result.films.get(name, result.film)
    sampler = settings.sampler
    metadata: dict[str, object] = {
        "software": f"clrender {__version__}",
        "scene": labels.scene,
        "spp": sampler.n,
        "sampler": sampler.name,
        "estimator": name,
        "seed": settings.seed,
        "device": labels.device,
        "render_time_s": stats.wall_seconds,
        "device_time_s": stats.device_seconds,
        "host_time_s": stats.host_seconds,
        "compile_time_s": stats.compile_seconds,
        "setup_compile_time_s": stats.setup_compile_seconds,
        "worker_setup_time_s": stats.worker_setup_seconds,
        **{f"{stage}_time_s": stats.stage_seconds[stage] for stage in DEVICE_STAGES},
        "partial": int(not film.complete),
        "rendered_pixels": film.rendered_count,
        "traced_samples": stats.traced_samples,
        "rays": stats.rays,
        "redrawn_pixels": stats.redrawn_pixels,
        "unresolved_pixels": stats.unresolved_pixels,
        "nonfinite_samples": stats.nonfinite_samples,
        "flagged_pixels": film.flagged_count,
        "layers": ",".join(LAYER_NAMES),
    }
    group = estimator_group(stats.estimator_seconds, name)
    if group is not None:
        metadata["estimator_time_s"] = stats.estimator_seconds[group]
        if group != name:
            metadata["estimator_timed_with"] = group
    if len(settings.estimators) > 1:
        metadata["estimators"] = ",".join(entry.name for entry in settings.estimators)
    noise = own_noise(result, name)
    if noise is not None:
        metadata["noise_mse"] = noise
    if sampler.toroidal_shift:
        metadata["toroidal_shift"] = 1
    if sampler.is_sppp:
        metadata.update(sppp_alpha=sampler.alpha, sppp_eps=sampler.eps, sppp_aux=sampler.n_aux)
    metadata["voronoi_backend"] = settings.voronoi_backend
    for key in ("scene_file", "scene_sha256", "kernels_sha256", "code_sha256", "device_precision"):
        value = getattr(labels, key)
        if value is not None:
            metadata[key] = value
    if result.trace_kernel is not None:  # (the same image whichever kernel traced it)
        metadata["trace_kernel"] = result.trace_kernel
    if labels.max_depth is not None:
        metadata["max_depth"] = labels.max_depth
    if labels.russian_roulette is not None:
        metadata["russian_roulette"] = int(labels.russian_roulette)
    for key, value in (errors or {}).items():
        if value is not None and key != "summary":
            metadata[f"error_{key}"] = value
    return metadata


def own_noise(result: RenderResult, estimator: str) -> float | None:
    """The mean of the variance layer over the rendered pixels where it is the estimator's own
    unbiased variance (clrender.estimators.variance), else None: not for a render that redrew
    pixels (their accepted draws are conditioned on acceptance), nor where it is not finite
    (one sample per pixel)."""
    entry = next(entry for entry in result.settings.estimators if entry.name == estimator)
    layers = result.layers_of(estimator)
    film = result.films[estimator]
    if layers is None or result.stats.redrawn_pixels or not film.rendered.any():
        return None
    if not variance_is_unbiased(entry, result.settings.sampler):
        return None
    noise = float(layers.variance[film.rendered].mean(dtype="float64"))
    return noise if math.isfinite(noise) else None


def estimator_group(estimator_seconds: dict[str, float], name: str) -> str | None:
    """The key its host time is filed under: the name, or its group's names joined by +."""
    for group in estimator_seconds:
        if name in group.split("+"):
            return group
    return None


def exr_layers(result: RenderResult, estimator: str) -> dict:
    """The per-pixel layers of one estimator's EXR, by channel name (LAYER_NAMES)."""
    film = result.films[estimator]
    layers = result.layers_of(estimator).images()
    layers["flagged"] = film.flagged.reshape(film.height, film.width)
    return {name: layers[name] for name in LAYER_NAMES}


def format_seconds(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f} s" if seconds >= 0.1 or seconds == 0 else f"{seconds:.3f} s"
    minutes, secs = divmod(int(round(seconds)), 60)
    return f"{minutes} min {secs:02d} s"


def rate(count: int, seconds: float) -> str:
    """'1.23 M/s' style throughput."""
    per_second = count / seconds if seconds > 0 else 0.0
    for scale, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if per_second >= scale:
            return f"{per_second / scale:.2f} {unit}/s"
    return f"{per_second:.0f} /s"


def summary_lines(result: RenderResult, labels: RenderLabels) -> list[str]:
    settings, stats, film = result.settings, result.stats, result.film
    sampler = settings.sampler
    status = "interrupted" if stats.interrupted else "done"
    overlap = "on" if settings.overlap else "off"
    tiles = f"{stats.tiles} tile" + ("" if stats.tiles == 1 else "s")
    names = " ".join(entry.name for entry in settings.estimators)
    stages = ", ".join(
        f"{stage.replace('_', ' ')} {format_seconds(stats.stage_seconds[stage])}"
        for stage in DEVICE_STAGES
    )
    estimators = ", ".join(
        f"{group} {format_seconds(seconds)}" for group, seconds in stats.estimator_seconds.items()
    )
    setup = stats.worker_setup_seconds  # a cluster render's (0 for a local one)
    builds = format_seconds(stats.setup_compile_seconds)
    before = (
        f"{builds} for the radiance sources; waited {format_seconds(setup)} for the workers' set-up"
        if setup
        else f"{builds} before the render"
    )
    excluded = "kernel builds and the workers' set-up" if setup else "kernel builds"
    return [
        f"{labels.scene}: {settings.width}x{settings.height}, {sampler.n} spp, "
        f"{sampler.name}{' (toroidal shift)' if sampler.toroidal_shift else ''} + "
        f"{names}, seed {settings.seed} on {labels.device}",
        f"{status}: {film.rendered_count}/{film.pixel_count} pixels in "
        f"{format_seconds(stats.wall_seconds)} (device {format_seconds(stats.device_seconds)}, "
        f"host estimators {format_seconds(stats.host_seconds)}, {tiles}, "
        f"overlap {overlap}; kernel builds {format_seconds(stats.compile_seconds)}, and {before})",
        f"device stages: {stages}; host: {estimators or 'none'}",
        f"paths {stats.traced_samples:,} ({rate(stats.traced_samples, stats.run_seconds)}"
        f"{'' if result.trace_kernel is None else ', ' + result.trace_kernel + ' kernel'}), "
        f"rays {stats.rays:,} ({rate(stats.rays, stats.run_seconds)}), without {excluded}",
        f"rejections: {stats.redrawn_pixels} pixel redraws, {stats.unresolved_pixels} pixels "
        f"unresolved (mc fallback); non-finite samples: {stats.nonfinite_samples}, "
        f"flagged pixels: {film.flagged_count}",
    ]


def summary_json(
    result: RenderResult,
    labels: RenderLabels,
    outputs: dict,
    errors: dict[str, dict],
    reference: str | None,
) -> dict[str, object]:
    """The closing summary as JSON-ready data: the render's settings and status, its timings
    split by stage, and per estimator its files, its EXR metadata and its errors against the
    reference (None without one, or for a partial render)."""
    settings, stats = result.settings, result.stats
    timings = {
        "wall_s": stats.wall_seconds,
        "run_s": stats.run_seconds,
        "compile_s": stats.compile_seconds,
        "setup_compile_s": stats.setup_compile_seconds,
        "worker_setup_s": stats.worker_setup_seconds,
        "device_s": stats.device_seconds,
        **{f"{stage}_s": stats.stage_seconds[stage] for stage in DEVICE_STAGES},
        "host_s": stats.host_seconds,
        "estimators_s": dict(stats.estimator_seconds),
        "redraw_host_s": stats.redraw_host_seconds,
        "layers_s": stats.layer_seconds,
    }
    images = {}
    for name, pair in outputs.items():
        measured = errors.get(name)
        images[name] = {
            "exr": str(pair.exr),
            "png": str(pair.png),
            "metadata": render_metadata(result, labels, name, measured),
            "errors": None
            if measured is None
            else {key: value for key, value in measured.items() if key != "summary"},
        }
    return {
        "status": "interrupted" if stats.interrupted else "done",
        "scene": labels.scene,
        "width": settings.width,
        "height": settings.height,
        "spp": settings.sampler.n,
        "sampler": settings.sampler.name,
        "estimators": [entry.name for entry in settings.estimators],
        "seed": settings.seed,
        "device": labels.device,
        "trace_kernel": result.trace_kernel,  # None for an analytic image
        "tasks_by_worker": result.tasks_by_worker,  # through an executor; None otherwise
        "paths_per_second": stats.traced_samples / stats.run_seconds if stats.run_seconds else 0,
        "timings": timings,
        "reference": reference,
        "images": images,
    }


def json_ready(value: object) -> object:
    """value with every non-finite float replaced by None (JSON has no NaN or Infinity)."""
    if isinstance(value, dict):
        return {key: json_ready(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
