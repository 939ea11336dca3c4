"""Whole-scene checks of a loaded scene's geometry against the device's float32 arithmetic and
the camera's placement: what no single field's check can see.

- The scene's extent (its shapes' bounding box with the camera's look_from) must be at least
  MIN_SCENE_EXTENT, so that squares and products of lengths (ray-sphere discriminants, quad
  normals) stay normal float32 numbers with all their digits: an error otherwise (a scene
  scaled by 1e-30 renders black).
- A shape smaller than RESOLVED_BITS bits of float32 resolution at its distance (from the
  origin, where the device stores it, and from the camera, along the rays that reach it) has
  lost its shape on the device: a warning (the image is right only where that shape does not
  show). Spheres by their radius, quads by their shorter edge, a mesh's triangles by their
  shortest edge: a mesh is named when such triangles make MESH_UNRESOLVED_AREA or more of its
  area (a few slivers of a fine model are no harm; a whole model too small for its place is).
- The camera on a surface (look_from on a quad, within its edges, on a sphere, or on a mesh's
  triangle, to within the float32 rounding of look_from itself): camera rays start on that
  surface and the image is black or wrong, e.g. the furnace's back wall tilted through the
  camera: a warning.

The mesh checks are NumPy over every triangle, MESH_CHUNK at a time: 1 M triangles take about
0.1-0.2 s of CPU (README, "Scene file format").

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
# A mesh is named as below float32 resolution when its unresolved triangles make this share of
# its area or more
MESH_UNRESOLVED_AREA = 0.01
# Triangles a mesh check reads at a time (bounded memory: ~50 bytes a triangle per array)
MESH_CHUNK = 1 << 18
# Slack of the barycentric coordinates of a point on a triangle (as the quads' edge slack)
BARYCENTRIC_SLACK = 1e-6


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


@dataclass(frozen=True)
class MeshGeometry:
    """A mesh as the checks see it: its vertices (V, 3) float64 and triangles (T, 3)."""

    label: str  # as errors name it: shapes[3] ('bunny')
    positions: np.ndarray
    indices: np.ndarray

    def chunks(self):
        """(first triangle, vertex indices, p0, p1, p2) of MESH_CHUNK triangles at a time."""
        for first in range(0, len(self.indices), MESH_CHUNK):
            corners = self.indices[first : first + MESH_CHUNK]
            points = (np.take(self.positions, corners[:, k], axis=0) for k in range(3))
            yield first, corners, *points

    def triangle_under(self, point: np.ndarray, tolerance: float) -> int | None:
        """The first triangle the point lies on, to within `tolerance` of its plane and
        BARYCENTRIC_SLACK of its edges, or None."""
        # Triangles whose bounding box (widened by the tolerance) holds the point, from each
        # vertex's side of the point on each axis
        offset = self.positions - point
        below, above = offset <= tolerance, offset >= -tolerance
        for first in range(0, len(self.indices), MESH_CHUNK):
            corners = self.indices[first : first + MESH_CHUNK]
            near = np.ones(len(corners), bool)
            for axis in range(3):
                low, high = below[:, axis][corners], above[:, axis][corners]
                near &= low.any(axis=1) & high.any(axis=1)
            candidates = np.flatnonzero(near)
            if len(candidates) == 0:
                continue
            p0, p1, p2 = (self.positions[corners[candidates, k]] for k in range(3))
            e1, e2, v = p1 - p0, p2 - p0, point - p0
            normal = np.cross(e1, e2)
            length = np.linalg.norm(normal, axis=1)
            on_plane = np.abs(np.einsum("ij,ij->i", normal, v)) <= tolerance * length
            # Barycentric coordinates (b1 along e1, b2 along e2) of the point's projection
            d11, d12, d22 = (np.einsum("ij,ij->i", a, b) for a, b in ((e1, e1), (e1, e2), (e2, e2)))
            dv1, dv2 = np.einsum("ij,ij->i", v, e1), np.einsum("ij,ij->i", v, e2)
            with np.errstate(divide="ignore", invalid="ignore"):
                denominator = d11 * d22 - d12 * d12
                b1 = (d22 * dv1 - d12 * dv2) / denominator
                b2 = (d11 * dv2 - d12 * dv1) / denominator
            inside = (b1 >= -BARYCENTRIC_SLACK) & (b2 >= -BARYCENTRIC_SLACK)
            inside &= b1 + b2 <= 1.0 + BARYCENTRIC_SLACK
            hits = np.flatnonzero(on_plane & inside & (length > 0.0))
            if len(hits):
                return first + int(candidates[hits[0]])
        return None

    def unresolved_note(self, look_from: np.ndarray) -> str | None:
        """A warning when triangles below RESOLVED_BITS bits of float32 resolution at their
        distance (by their shortest edge) make MESH_UNRESOLVED_AREA or more of the mesh's
        area, else None."""
        # Each vertex's distance from the origin or camera (as unresolved_shape_notes measures)
        reach = np.maximum(
            np.abs(self.positions).max(axis=1), np.abs(self.positions - look_from).max(axis=1)
        )
        # The small triangles by squared lengths (no square roots, no areas unless some are)
        small, shortest, distance = [], [], []
        for first, corners, p0, p1, p2 in self.chunks():
            farthest = np.maximum(reach[corners[:, 0]], reach[corners[:, 1]])
            step = np.maximum(farthest, reach[corners[:, 2]]) * (
                FLOAT32_EPSILON * 2.0**RESOLVED_BITS
            )
            edges = [np.einsum("ij,ij->i", b - a, b - a) for a, b in ((p0, p1), (p1, p2), (p2, p0))]
            squared = np.minimum(np.minimum(edges[0], edges[1]), edges[2])
            found = np.flatnonzero(squared < step * step)
            small.append(first + found)
            shortest.append(np.sqrt(squared[found]))
            distance.append(step[found] / (FLOAT32_EPSILON * 2.0**RESOLVED_BITS))
        small = np.concatenate(small)
        count = len(small)
        if count == 0:
            return None
        size, distance = (float(np.concatenate(values)[0]) for values in (shortest, distance))
        first_small = int(small[0])
        chunks = self.chunks()
        total_area = sum(float(triangle_areas(p0, p1, p2).sum()) for *_, p0, p1, p2 in chunks)
        corners = self.indices[small]
        small_area = float(triangle_areas(*(self.positions[corners[:, k]] for k in range(3))).sum())
        if count == 0 or small_area < MESH_UNRESOLVED_AREA * total_area:
            return None
        return (
            f"{self.label}: {count} of its {len(self.indices)} triangles "
            f"({100.0 * small_area / max(total_area, 1e-300):.3g} % of its area) span under "
            f"{2**RESOLVED_BITS} float32 steps at their distance from the origin or camera "
            f"(the first, triangle {first_small}: its shortest edge {size:.3g}, a step "
            f"{distance * FLOAT32_EPSILON:.3g} at {distance:.3g}): the device renders them as "
            "noise or not at all"
        )


def triangle_areas(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)


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


def unresolved_shape_notes(
    shapes: Sequence[ShapeGeometry], look_from: np.ndarray, meshes: Sequence[MeshGeometry] = ()
) -> list[str]:
    """Warnings for shapes smaller than RESOLVED_BITS bits of float32 resolution at their
    distance, and meshes whose triangles are (MeshGeometry.unresolved_note): at most
    MAX_SHAPES_LISTED named, then a count."""
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
    for mesh in meshes:
        note = mesh.unresolved_note(look_from)
        if note is not None:
            notes.append(note)
    if len(notes) > MAX_SHAPES_LISTED:
        more = len(notes) - MAX_SHAPES_LISTED
        notes = notes[:MAX_SHAPES_LISTED] + [f"... and {more} more shapes below float32 resolution"]
    return notes


def camera_on_surface(
    shapes: Sequence[ShapeGeometry], look_from: np.ndarray, meshes: Sequence[MeshGeometry] = ()
) -> str | None:
    """The first shape (quads and spheres, then meshes' triangles) whose surface look_from lies
    on (within the device's rounding of a hit there), as a warning, or None. On means within
    the float32 rounding of look_from itself: a large shape's own magnitude does not widen it
    (a 2e9-wide ground quad under the camera is no surface the camera is on)."""
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
        return on_surface_note(look_from, shape.label)
    for mesh in meshes:
        triangle = mesh.triangle_under(look_from, tolerance)
        if triangle is not None:
            return on_surface_note(look_from, f"{mesh.label} (its triangle {triangle})")
    return None


def on_surface_note(look_from: np.ndarray, label: str) -> str:
    return (
        f"[camera] look_from {list(map(float, look_from))} lies on {label}: camera rays start "
        "on its surface, so the image is black or wrong; move the camera off it"
    )
