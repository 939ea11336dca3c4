"""What an image was made from, as short fingerprints for its metadata: the scene as the device
gets it, whatever file it came from, the OpenCL sources that traced it and clrender's Python
code that ran the render. Two renders with equal fingerprints, settings and device give the
same image; a scene file edited under the same name, a changed kernel or a changed module
gives another fingerprint."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

import clrender
from clrender.code_sources import FINGERPRINT_DIGITS, python_sources_fingerprint
from clrender.errors import ClrenderError
from clrender.runtime import built_sources_fingerprints, kernels_dir
from clrender.scene import Scene

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


def code_fingerprint() -> str:
    """SHA-256 of clrender's Python sources (clrender.code_sources.python_sources_fingerprint
    of the package folder) as they were when this process imported clrender: computed once
    then, from the files' bytes (about a millisecond for its 0.8 MB), and kept
    (clrender.CODE_SHA256), so a module edited afterwards does not change it: a process keeps
    the modules it imported. clrender imports some modules only when first used, so the files
    are fingerprinted again when asked (about a millisecond): if they changed since the import
    (edited in a notebook's session), the value is "<at import>+<now>", as the process may run
    either."""
    now = python_sources_fingerprint(Path(clrender.__file__).parent)
    at_import = clrender.CODE_SHA256
    return at_import if now == at_import else f"{at_import}+{now}"


class ProvenanceWarning(UserWarning):
    """A render's workers ran other clrender code or built other OpenCL sources than this
    process (provenance_warning)."""


class KernelsWarning(ProvenanceWarning):
    """A ProvenanceWarning whose workers built other OpenCL sources than this process (or
    could not tell which), whatever their code: what it meant before code_sha256 was recorded,
    so a filter on it keeps catching those."""


def local_kernels_fingerprint() -> str | None:
    """This process's kernels fingerprint (clrender.provenance.kernels_fingerprint), None where
    it has no kernels folder (a cluster's client needs none: its workers build)."""
    try:
        return kernels_fingerprint()
    except (ClrenderError, OSError):
        return None


# The fingerprints a render's workers report (RenderResult, RenderLabels and the metadata keys),
# with what each is of and what its workers did with it, for provenance_warning
REPORTED = {
    "code_sha256": ("clrender code", "ran"),
    "kernels_sha256": ("OpenCL sources", "built"),
}


def reported(carrier) -> dict[str, str | None]:
    """The REPORTED fingerprints of a RenderResult (its workers', None for a local render) or
    of RenderLabels, by key."""
    return {key: getattr(carrier, key, None) for key in REPORTED}


def local_fingerprints() -> dict[str, str | None]:
    """This process's values of the fingerprints workers report (REPORTED)."""
    return {"code_sha256": code_fingerprint(), "kernels_sha256": local_kernels_fingerprint()}


def provenance_warning(
    workers: dict[str, str | None], ours: dict[str, str | None]
) -> ProvenanceWarning | None:
    """One line, as a warning, when a render's workers (their fingerprints by REPORTED key:
    RenderResult.code_sha256 and .kernels_sha256, None for a local render) ran other clrender
    code or built other OpenCL sources than this process's (`ours`), or some could not tell
    ("unknown": a clrender older than that report): such an image need not equal a local
    render's. A KernelsWarning when the OpenCL sources are among them, else a
    ProvenanceWarning; None when they agree."""
    differ, unknown, keys = [], [], set()
    for key, (what, did) in REPORTED.items():
        theirs, mine = workers.get(key), ours.get(key)
        if theirs is None or theirs == mine:
            continue
        keys.add(key)
        label = key.removesuffix("_sha256")
        known = [value for value in theirs.split("; ") if not value.startswith("unknown")]
        if all(value == mine for value in known):
            unknown.append(f"which {what} it {did} ({label} {theirs})")
        else:
            here = mine or f"no {label} folder here"
            differ.append(f"{did} other {what} ({label} {theirs}) than this clrender ({here})")
    if not keys:
        return None
    parts = [f"the workers {' and '.join(differ)}"] if differ else []
    if unknown:
        told = " nor ".join(unknown)
        parts.append(f"a worker could not tell {told}: a clrender older than that report")
    kind = KernelsWarning if "kernels_sha256" in keys else ProvenanceWarning
    return kind("; ".join(parts) + "; the images record the workers' values")
