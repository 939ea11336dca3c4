"""clrender: an OpenCL path tracer with Voronoi-weighted pixel estimators.

    import clrender

    scene = clrender.load_scene("cornell-box")
    result = clrender.render(scene, spp=64, estimator="vor_sn", resolution=64)
    result.image  # (64, 64, 3) float32 linear RGB
    clrender.preview(result)  # a tone-mapped sRGB preview (a PIL image: notebooks show it)

clrender.image_errors(image, reference) gives MSE and relative MSE (clrender.compare).
clrender.ESTIMATORS lists every pixel estimator (clrender.estimators.registry); errors a user
can fix are clrender.ClrenderError with a one-line message.
"""

import os

from clrender.code_sources import python_sources_fingerprint
from clrender.errors import ClrenderError, ParameterError

__version__ = "0.1.0"
__all__ = [
    "ESTIMATORS",
    "ClrenderError",
    "ParameterError",
    "RenderInterrupted",
    "__version__",
    "image_errors",
    "load_scene",
    "preview",
    "render",
]

# The fingerprint of this package's Python code as it was on import: the code this process
# runs (clrender.provenance.code_fingerprint)
CODE_SHA256 = python_sources_fingerprint(os.path.dirname(os.path.abspath(__file__)))

# The front door is imported on first use, so that `python -m clrender` can set up the process
# (one BLAS thread, clrender/__main__.py) before NumPy loads.
_LAZY = {
    "load_scene": "clrender.api",
    "render": "clrender.api",
    "RenderInterrupted": "clrender.api",
    "ESTIMATORS": "clrender.estimators",
    "image_errors": "clrender.compare",
    "preview": "clrender.display",
}


# Submodules a user reaches as attributes (clrender.compare.read_reference) without importing
_SUBMODULES = ("compare",)


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    if name in _SUBMODULES:
        import importlib

        return importlib.import_module(f"clrender.{name}")
    raise AttributeError(f"module 'clrender' has no attribute {name!r}")
