"""What a render reports: the EXR metadata and the closing summary."""

from __future__ import annotations

from dataclasses import dataclass

from clrender import __version__
from clrender.pipeline import RenderResult


@dataclass(frozen=True)
class RenderLabels:
    """Descriptions the pipeline itself does not know."""

    scene: str
    device: str
    max_depth: int | None  # None for sources without paths (analytic images)


def render_metadata(result: RenderResult, labels: RenderLabels) -> dict[str, object]:
    """EXR header attributes describing the render (see clrender.imageio for their types)."""
    settings, stats, film = result.settings, result.stats, result.film
    sampler = settings.sampler
    metadata: dict[str, object] = {
        "software": f"clrender {__version__}",
        "scene": labels.scene,
        "spp": sampler.n,
        "sampler": sampler.name,
        "estimator": settings.estimator.name,
        "seed": settings.seed,
        "device": labels.device,
        "render_time_s": stats.wall_seconds,
        "device_time_s": stats.device_seconds,
        "host_time_s": stats.host_seconds,
        "partial": int(not film.complete),
        "rendered_pixels": film.rendered_count,
        "traced_samples": stats.traced_samples,
        "rays": stats.rays,
        "redrawn_pixels": stats.redrawn_pixels,
        "unresolved_pixels": stats.unresolved_pixels,
        "nonfinite_samples": stats.nonfinite_samples,
        "flagged_pixels": film.flagged_count,
    }
    if sampler.toroidal_shift:
        metadata["toroidal_shift"] = 1
    if sampler.is_sppp:
        metadata.update(sppp_alpha=sampler.alpha, sppp_eps=sampler.eps, sppp_aux=sampler.n_aux)
    if labels.max_depth is not None:
        metadata["max_depth"] = labels.max_depth
    return metadata


def format_seconds(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f} s"
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
    return [
        f"{labels.scene}: {settings.width}x{settings.height}, {sampler.n} spp, "
        f"{sampler.name}{' (toroidal shift)' if sampler.toroidal_shift else ''} + "
        f"{settings.estimator.name}, seed {settings.seed} on {labels.device}",
        f"{status}: {film.rendered_count}/{film.pixel_count} pixels in "
        f"{format_seconds(stats.wall_seconds)} (device {format_seconds(stats.device_seconds)}, "
        f"host Voronoi {format_seconds(stats.host_seconds)}, {stats.tiles} tiles, "
        f"overlap {overlap})",
        f"paths {stats.traced_samples:,} ({rate(stats.traced_samples, stats.wall_seconds)}), "
        f"rays {stats.rays:,} ({rate(stats.rays, stats.wall_seconds)})",
        f"rejections: {stats.redrawn_pixels} pixel redraws, {stats.unresolved_pixels} pixels "
        f"unresolved (mc fallback); non-finite samples: {stats.nonfinite_samples}, "
        f"flagged pixels: {film.flagged_count}",
    ]
