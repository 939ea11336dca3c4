"""Voronoi cell areas from a Delaunay triangulation: the geometry shared by the per-pixel Qhull
cells (clrender.estimators.qhull_cells) and the image-level tessellation
(clrender.estimators.image).

For a Delaunay triangle (a, b, c) with circumcentre o, the part of a's Voronoi cell inside the
triangle's "star" is the quadrilateral (a, mid(a, b), o, mid(c, a)); its signed area (positive
for counter-clockwise triangles) is 0.25 * cross(b - c, o - a). Summed over all triangles
around a bounded cell these pieces telescope to the cell polygon, so np.bincount over the three
vertex columns gives every cell area from one pass over the triangles. Sign conventions are
fixed by |det|, so Qhull's triangle orientation does not matter.

Coincident points (Qhull reports all but one as "coplanar") split their common cell equally:
share_coincident. Qhull also drops distinct points it cannot tell apart at its precision
(nearly coincident ones), or triangulates them wrongly; sharing is wrong for those, and the
callers must find them (clrender.estimators.qhull_cells and clrender.estimators.image do, and
settle their cells by clipping).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # scipy.spatial is imported where used: it takes ~1 s to import
    from scipy.spatial import Delaunay

# SciPy's default for 2-D Delaunay ("Qt" is always added by SciPy). No "QJ": joggling moves the
# points and so changes the cells.
QHULL_OPTIONS = "Qbb Qc Qz Q12"


def share_coincident(tri: Delaunay, areas: np.ndarray, *flags: np.ndarray | None) -> None:
    """Coincident points: the vertex Qhull kept and the points it dropped share the cell, so
    the kept vertex's area is split equally and every point gets the share and the kept
    vertex's flags (in place; flags given as None are skipped).

    Right for exact duplicates (identical coordinates) only: a point Qhull dropped because it
    was too close to the kept vertex for Qhull's precision has a cell of its own, and the
    shares are then wrong; the caller must detect that case (tri.coplanar rows whose points'
    coordinates differ)."""
    if not len(tri.coplanar):
        return
    dropped, kept = tri.coplanar[:, 0], tri.coplanar[:, 2]
    areas /= 1.0 + np.bincount(kept, minlength=len(areas))
    areas[dropped] = areas[kept]
    for flag in flags:
        if flag is not None:
            flag[dropped] = flag[kept]


def as_complex(points: np.ndarray) -> np.ndarray:
    """(K, 2) float64 points as (K,) complex128 x + iy (a view when already contiguous)."""
    return np.ascontiguousarray(points, dtype=np.float64).view(np.complex128).reshape(-1)


class TriangleTerms:
    """Per-triangle terms of triangles (a, b, c) of complex points z = x + iy: e1 = b - a,
    e2 = c - a, l1 = |e1|^2, l2 = |e2|^2, det = e1 x e2, and pieces[j], the signed area vertex
    j's cell gets from the triangle."""

    def __init__(self, z: np.ndarray, s: np.ndarray) -> None:
        a, b, c = s
        self.za = za = z.take(a)
        self.e1 = e1 = z.take(b)
        e1 -= za
        self.e2 = e2 = z.take(c)
        e2 -= za
        self.l1 = l1 = _squared_norm(e1)
        self.l2 = l2 = _squared_norm(e2)
        w = e1.conjugate()
        w *= e2  # conj(e1) e2 = (e1 . e2) + i (e1 x e2)
        dot, self.det = w.real, w.imag
        # With U = (e2y l1 - e1y l2, e1x l2 - e2x l1), o - a = U / (2 det); the quadrilateral
        # areas 0.25 cross(b - c, o - a) etc. reduce to these forms (k = 1 / (8 |det|)).
        k = np.abs(self.det)
        half_tri = 0.25 * k
        np.divide(0.125, k, out=k)
        t1 = l2 - dot
        t1 *= l1
        t2 = l1 - dot
        t2 *= l2
        self.pieces = pieces = np.empty((3, len(k)))
        np.add(t1, t2, out=pieces[0])
        pieces[0] *= k
        np.multiply(k, t2, out=pieces[1])
        np.subtract(half_tri, pieces[1], out=pieces[1])
        np.multiply(k, t1, out=pieces[2])
        np.subtract(half_tri, pieces[2], out=pieces[2])

    def circumcentre_offset(self) -> tuple[np.ndarray, np.ndarray]:
        """u = o - a, the circumcentre relative to vertex a."""
        inv = 0.5 / self.det
        e1x, e1y, e2x, e2y = self.e1.real, self.e1.imag, self.e2.real, self.e2.imag
        ux = (e2y * self.l1 - e1y * self.l2) * inv
        uy = (e1x * self.l2 - e2x * self.l1) * inv
        return ux, uy

    def circumcircle(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Circumcentres (cx, cy) and circumradii."""
        ux, uy = self.circumcentre_offset()
        return self.za.real + ux, self.za.imag + uy, np.sqrt(ux * ux + uy * uy)


def _squared_norm(e: np.ndarray) -> np.ndarray:
    norm = e.real * e.real
    norm += e.imag * e.imag
    return norm
