"""A render's files: OUT.exr (RGB, per-pixel layers, metadata with provenance and errors) and
OUT.png per estimator, written together and atomically. The command line and
`RenderResult.save` write them alike."""

from __future__ import annotations

import signal
from dataclasses import dataclass
from pathlib import Path

from clrender import interrupts
from clrender.errors import ParameterError


@dataclass(frozen=True)
class OutputPaths:
    exr: Path
    png: Path


def output_paths(
    output: str | None,
    scene_label: str,
    estimators: list[str] | None = None,
    option: str = "-o/--output",
) -> dict[str, OutputPaths]:
    """OUT.exr and OUT.png for one estimator, OUT.<estimator>.exr and .png for each of several,
    all checked writable before anything renders; option names the path in messages."""
    from clrender.imageio import check_writable

    if output is not None and not output.strip():
        raise ParameterError(f"{option} is empty: give a file name such as out.exr")
    exr = Path(output) if output else Path(scene_label.replace(":", "-") + ".exr")
    if exr.name.lower() in (".exr", ".png"):
        raise ParameterError(f"{option} {str(exr)!r} has no file name before {exr.name}")
    if output and exr.suffix == "" and exr.exists() and not exr.is_file():
        raise ParameterError(
            f"{option} {str(exr)!r} is not a file name (a directory or device): clrender "
            "writes OUT.exr and OUT.png, give OUT"
        )
    if exr.suffix.lower() != ".exr":
        if exr.suffix:
            raise ParameterError(f"{option} must name an .exr file, got {str(exr)!r}")
        exr = exr.with_suffix(".exr")
    names = estimators or [""]
    paths = {}
    for name in names:
        named = exr.with_name(f"{exr.stem}.{name}{exr.suffix}") if len(names) > 1 else exr
        paths[name] = OutputPaths(check_writable(named), check_writable(named.with_suffix(".png")))
    return paths


def write_outputs(result, labels, paths: dict[str, OutputPaths], errors: dict) -> None:
    """Every estimator's EXR (RGB, the per-pixel layers, the metadata with its errors) and PNG,
    each checked on disk before any replaces its old version."""
    from clrender.imageio import (
        exr_header,
        exr_writer,
        png_writer,
        rgb_float32,
        write_all_atomically,
    )
    from clrender.report import exr_layers, render_metadata

    jobs = []
    for name, pair in zip(result.films, paths.values(), strict=True):
        image = rgb_float32(result.films[name].image())
        header = exr_header(render_metadata(result, labels, name, errors.get(name)))
        jobs.append((pair.exr, exr_writer(image, header, exr_layers(result, name))))
        jobs.append((pair.png, png_writer(image)))
    write_all_atomically(jobs)


def render_labels(label: str, scene, max_depth, roulette, result=None):
    """The render's RenderLabels: what the pipeline does not know, provenance included; the
    device, its precision and the kernels' and code's fingerprints are the result's
    (RenderResult.device, .device_precision, .kernels_sha256, .code_sha256: for a cluster
    render its workers', reported by its tasks), the device and precision None before the
    render, the fingerprints this process's (local_kernels_fingerprint, code_fingerprint)."""
    from clrender.provenance import code_fingerprint, local_kernels_fingerprint, scene_fingerprint
    from clrender.report import RenderLabels

    return RenderLabels(
        label,
        None if result is None else result.device,
        max_depth,
        roulette,
        scene_file=None if scene is None else str(Path(scene.path).resolve()),
        scene_sha256=None if scene is None else scene_fingerprint(scene),
        kernels_sha256=getattr(result, "kernels_sha256", None) or local_kernels_fingerprint(),
        device_precision=None if result is None else result.device_precision,
        code_sha256=getattr(result, "code_sha256", None) or code_fingerprint(),
    )


def save(result, output: str | Path) -> dict[str, OutputPaths]:
    """Write a render's files as the command line does (OUT.exr and OUT.png; with several
    estimators OUT.<estimator>.exr and .png each), atomically: a failed write keeps the old
    files. The result must come from clrender.render (which records its labels: scene,
    device, provenance). Returns the paths written, by estimator."""
    labels = getattr(result, "labels", None)
    if labels is None:
        raise ParameterError(
            "this RenderResult carries no labels (scene, device, provenance): save the result "
            "of clrender.render"
        )
    if not any(film.rendered_count for film in result.films.values()):
        raise ParameterError(
            "nothing to save: the render was interrupted before any pixel was finished (an "
            "all-black image would replace the previous one)"
        )
    paths = output_paths(str(output), labels.scene, list(result.films), "save's path")
    # A signal while the files are replaced waits for the last one: an EXR and its PNG are
    # both the new ones or both the old ones; then it has its usual effect
    with interrupts.signals_held() as held:
        write_outputs(result, labels, paths, {})
    if held:
        signal.raise_signal(held[0])
    return dict(zip(result.films, paths.values(), strict=True))
