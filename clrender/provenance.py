"""What an image was made from, as short fingerprints for its metadata: the scene as the device
gets it, whatever file it came from, and the OpenCL sources that traced it. Two renders with
equal fingerprints, settings and device give the same image; a scene file edited under the
same name, or a changed kernel, gives another fingerprint."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from clrender.errors import ClrenderError
from clrender.runtime import built_sources_fingerprints, kernels_dir
from clrender.scene import Scene

FINGERPRINT_DIGITS = 16  # hex digits of SHA-256 kept: 64 bits, no collision among real scenes
SCENE_ARRAYS = ("materials", "quads", "spheres", "emitters", "triangles", "triangle_normals")


def scene_fingerprint(scene: Scene) -> str:
    """SHA-256 of the scene as the device gets it: its camera (resolution included), materials,
    shapes and emitters; not its file's name or text (a comment or a reordered table changes
    nothing the device sees)."""
    digest = hashlib.sha256(repr(scene.camera).encode())
    for name in SCENE_ARRAYS:
        array = np.ascontiguousarray(getattr(scene, name))
        digest.update(f"{name} {array.dtype.str} {array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()[:FINGERPRINT_DIGITS]


def kernels_fingerprint() -> str:
    """SHA-256 of the OpenCL sources renders build from (kernels_dir(): $CLRENDER_KERNELS_DIR or
    the packaged ones): those this process built its programs from, when it did (fingerprinted
    at its first build from that folder; a later build that found the files changed adds its
    own, joined by "+": the programs then come from both), else the folder's sources now. A
    process keeps its built programs, so a source edited after the builds does not change what
    it renders with, nor this fingerprint (clrender.runtime.built_sources_fingerprints)."""
    folder = kernels_dir()
    return "+".join(built_sources_fingerprints(folder)) or sources_fingerprint(folder)


def sources_fingerprint(folder: Path) -> str:
    """SHA-256 of the OpenCL sources in a folder as they are now, by file name and content;
    the test kernels (*_test.cl) and research probes (*_probe.cl, built by bench/ scripts only)
    left out."""
    digest = hashlib.sha256()
    for source in sorted(folder.iterdir()):
        if source.suffix in (".cl", ".h") and not source.stem.endswith(("_test", "_probe")):
            digest.update(source.name.encode() + b"\0" + source.read_bytes())
    return digest.hexdigest()[:FINGERPRINT_DIGITS]


class KernelsWarning(UserWarning):
    """A render's workers built other OpenCL sources than this process (kernels_warning)."""


def local_kernels_fingerprint() -> str | None:
    """This process's kernels fingerprint (clrender.provenance.kernels_fingerprint), None where
    it has no kernels folder (a cluster's client needs none: its workers build)."""
    try:
        return kernels_fingerprint()
    except (ClrenderError, OSError):
        return None


def kernels_warning(workers: str | None, ours: str | None) -> str | None:
    """One line when a render's workers (RenderResult.kernels_sha256, None for a local render)
    built other OpenCL sources than this process's: such an image need not equal a local
    render's. None when they agree."""
    if workers is None or workers == ours:
        return None
    known = [value for value in workers.split("; ") if not value.startswith("unknown")]
    if all(value == ours for value in known):
        return (
            "a worker could not tell which OpenCL sources it built (a clrender older than "
            f"that report): the images record kernels {workers}"
        )
    return (
        f"the workers built other OpenCL sources (kernels {workers}) than this clrender "
        f"({ours or 'no kernels folder here'}); the images record theirs"
    )
