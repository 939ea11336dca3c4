"""What an image was made from, as short fingerprints for its metadata: the scene as the device
gets it, whatever file it came from, and the OpenCL sources that traced it. Two renders with
equal fingerprints, settings and device give the same image; a scene file edited under the
same name, or a changed kernel, gives another fingerprint."""

from __future__ import annotations

import hashlib

import numpy as np

from clrender.runtime import kernels_dir
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
    """SHA-256 of the OpenCL sources renders build (kernels_dir(): $CLRENDER_KERNELS_DIR or the
    packaged ones; the test kernels (*_test.cl) and research probes (*_probe.cl, built by bench/
    scripts only) left out), by file name and content."""
    digest = hashlib.sha256()
    for source in sorted(kernels_dir().iterdir()):
        if source.suffix in (".cl", ".h") and not source.stem.endswith(("_test", "_probe")):
            digest.update(source.name.encode() + b"\0" + source.read_bytes())
    return digest.hexdigest()[:FINGERPRINT_DIGITS]
