"""clrender: an OpenCL path tracer with Voronoi-weighted pixel estimators.

    import clrender

    scene = clrender.load_scene("cornell-box")
    result = clrender.render(scene, spp=64, estimator="vor_sn", resolution=64)
    result.image  # (64, 64, 3) float32 linear RGB

clrender.ESTIMATORS lists every pixel estimator (clrender.estimators.registry); errors a user
can fix are clrender.ClrenderError with a one-line message.
"""

__version__ = "0.1.0"

from clrender.api import load_scene, render  # noqa: E402
from clrender.errors import ClrenderError, ParameterError  # noqa: E402
from clrender.estimators import ESTIMATORS  # noqa: E402

__all__ = ["ESTIMATORS", "ClrenderError", "ParameterError", "__version__", "load_scene", "render"]
