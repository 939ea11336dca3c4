"""clrender: an OpenCL path tracer with Voronoi-weighted pixel estimators."""

__version__ = "0.1.0"
