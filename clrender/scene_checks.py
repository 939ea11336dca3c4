"""Whole-scene checks of a loaded scene's geometry against the device's float32 arithmetic and
the camera's placement: what no single field's check can see.

- The scene's extent (its shapes' bounding box with the camera's look_from) must be at least
  MIN_SCENE_EXTENT, so that squares and products of lengths (ray-sphere discriminants, quad
  normals) stay normal float32 numbers with all their digits: an error otherwise (a scene
  scaled by 1e-30 renders black).
- A shape smaller than RESOLVED_BITS bits of float32 resolution at its distance (from the
  origin, where the device stores it, and from the camera, along the rays that reach it) has
  lost its shape on the device: a warning (the image is right only where that shape does not
  show). Spheres by their radius, quads by their shorter edge.
- The camera on a surface (look_from on a quad, within its edges, or on a sphere, to within
  the float32 rounding of look_from itself): camera rays start on that surface and the image
  is black or wrong, e.g. the furnace's back wall tilted through the camera: a warning.

The tolerances follow the device's error bound for a hit point (kernels/geometry.h,
SURFACE_ERROR_SCALE = 32 float32 epsilons of the magnitudes involved).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

FLOAT32_EPSILON = float(np.finfo(np.float32).eps)
# Squares of lengths must keep 24 bits above float32's smallest normal (1.2e-38): 1e-15^2 =
# 1e-30 > 1.2e-38 * 2^24.
MIN_SCENE_EXTENT = 1e-15
# A shape keeps its form when its size spans at least 2^RESOLVED_BITS float32 steps at its
# distance.
RESOLVED_BITS = 4
# kernels/geometry.h: a hit point's rounding error is 32 float32 epsilons of its magnitude.
SURFACE_ERROR_SCALE = 32.0 * FLOAT32_EPSILON
MAX_SHAPES_LISTED = 3


@dataclass(frozen=True)
class ShapeGeometry:
    """A shape as the checks see it, float64: a quad (corner, edge1, edge2) or a sphere
    (center, radius)."""

    label: str  # as errors name it: shapes[3] ('left wall')
    corner: np.ndarray | None = None
    edge1: np.ndarray | None = None
    edge2: np.ndarray | None = None
    center: np.ndarray | None = None
    radius: float = 0.0

    @property
    def is_quad(self) -> bool:
        return self.corner is not None

    def points(self) -> list[np.ndarray]:
        """Points whose bounding box bounds the shape."""
        if self.is_quad:
            c, e1, e2 = self.corner, self.edge1, self.edge2
            return [c, c + e1, c + e2, c + e1 + e2]
        return [self.center - self.radius, self.center + self.radius]

    def size(self) -> float:
        if self.is_quad:
            return float(min(np.linalg.norm(self.edge1), np.linalg.norm(self.edge2)))
        return self.radius


def scene_extent(shapes: Sequence[ShapeGeometry], look_from: np.ndarray) -> float:
    """Diagonal of the bounding box of every shape and the camera position."""
    points = np.array([p for shape in shapes for p in shape.points()] + [look_from])
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def extent_error(shapes: Sequence[ShapeGeometry], look_from: np.ndarray) -> str | None:
    """Why the scene is too small for float32, or None."""
    extent = scene_extent(shapes, look_from)
    if extent >= MIN_SCENE_EXTENT:
        return None
    return (
        f"the scene spans only {extent:.3g} (shapes and camera): squares of its lengths "
        "underflow the device's float32; scale it to span at least "
        f"{MIN_SCENE_EXTENT:g}"
    )


def unresolved_shape_notes(shapes: Sequence[ShapeGeometry], look_from: np.ndarray) -> list[str]:
    """Warnings for shapes smaller than RESOLVED_BITS bits of float32 resolution at their
    distance (at most MAX_SHAPES_LISTED named, then a count)."""
    notes = []
    for shape in shapes:
        points = np.array(shape.points())
        distance = max(float(np.abs(points).max()), float(np.abs(points - look_from).max()), 1e-300)
        step = distance * FLOAT32_EPSILON
        if shape.size() >= step * 2.0**RESOLVED_BITS:
            continue
        what = "shorter edge" if shape.is_quad else "radius"
        notes.append(
            f"{shape.label}: its {what} {shape.size():.3g} spans under {2**RESOLVED_BITS} "
            f"float32 steps ({step:.3g}) at its distance {distance:.3g} from the origin or "
            "camera: the device renders it as noise or not at all"
        )
    if len(notes) > MAX_SHAPES_LISTED:
        more = len(notes) - MAX_SHAPES_LISTED
        notes = notes[:MAX_SHAPES_LISTED] + [f"... and {more} more shapes below float32 resolution"]
    return notes


def camera_on_surface(shapes: Sequence[ShapeGeometry], look_from: np.ndarray) -> str | None:
    """The first shape whose surface look_from lies on (within the device's rounding of a hit
    there), as a warning, or None. On means within the float32 rounding of look_from itself:
    a large shape's own magnitude does not widen it (a 2e9-wide ground quad under the camera
    is no surface the camera is on)."""
    tolerance = SURFACE_ERROR_SCALE * float(np.abs(look_from).max())
    for shape in shapes:
        if shape.is_quad:
            c, e1, e2 = shape.corner, shape.edge1, shape.edge2
            normal = np.cross(e1, e2)
            normal /= np.linalg.norm(normal)
            offset = look_from - c
            if abs(float(normal @ offset)) > tolerance:
                continue
            # Coordinates of the point in the quad's frame (least squares on the plane).
            frame = np.stack([e1, e2], axis=1)
            s, t = np.linalg.lstsq(frame, offset, rcond=None)[0]
            if not (-1e-6 <= s <= 1 + 1e-6 and -1e-6 <= t <= 1 + 1e-6):
                continue
        else:
            distance = float(np.linalg.norm(look_from - shape.center))
            if abs(distance - shape.radius) > tolerance:
                continue
        return (
            f"[camera] look_from {list(map(float, look_from))} lies on {shape.label}: camera "
            "rays start on its surface, so the image is black or wrong; move the camera off it"
        )
    return None
