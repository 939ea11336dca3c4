"""Reference Voronoi cells for the tests, in 60-digit decimal arithmetic.

A cell is a start box clipped by the bisector of every other nucleus, one after the other
(Sutherland-Hodgman, crossings interpolated along the edge): no early stop, no neighbour search,
no floating-point solve, so it shares neither code nor rounding with
clrender.estimators.clip_cells or Qhull. Float64 inputs are exact decimals, and 60 digits keep
every cell of the tests' clusters (nuclei down to 1e-9 apart, cells down to 1e-20 in area) far
more accurate than the tests' tolerances. Slow: for sets of about a hundred nuclei.
"""

from decimal import Decimal, localcontext

import numpy as np

DIGITS = 60


def exact_cells(nuclei: np.ndarray, others: np.ndarray, lo, hi, radii: bool = False) -> tuple:
    """(areas, touches): the areas of the cells of nuclei[i] ((K, 2)) among nuclei + others
    ((A, 2)) within the box [lo, hi] (per cell: (K, 2) arrays, or (2,) for all), coincident
    nuclei sharing a cell equally, and whether each cell reaches the box's boundary. With
    radii, also each cell's largest vertex distance from its nucleus (rounded to float): the
    cell is that among any superset of the points that adds none within twice this of it."""
    points = np.concatenate([nuclei, others])
    lo = np.broadcast_to(np.asarray(lo, float), nuclei.shape)
    hi = np.broadcast_to(np.asarray(hi, float), nuclei.shape)
    areas, touches = np.zeros(len(nuclei)), np.zeros(len(nuclei), bool)
    reach = np.zeros(len(nuclei))
    for i, a in enumerate(nuclei):
        coincident = (points == a).all(axis=1)
        area, touches[i], reach[i] = _cell(a, points[~coincident], lo[i], hi[i])
        areas[i] = area / coincident.sum()
    return (areas, touches, reach) if radii else (areas, touches)


def torus_copies(points: np.ndarray) -> np.ndarray:
    """The 8 translates x + (i, j), (i, j) != (0, 0), of every point."""
    shifts = [(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1) if (i, j) != (0, 0)]
    return np.concatenate([points + np.array(s, float) for s in shifts])


def _cell(a: np.ndarray, others: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """(area, touches the box, largest vertex distance) of the cell of a among others."""
    with localcontext() as context:
        context.prec = DIGITS
        ax, ay = Decimal(a[0]), Decimal(a[1])
        x0, y0, x1, y1 = (Decimal(v) for v in (lo[0], lo[1], hi[0], hi[1]))
        box = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
        poly = [(x - ax, y - ay) for x, y in box]  # relative to the nucleus
        order = np.argsort(np.hypot(*(others - a).T))  # nearest first: small polygons sooner
        for q in others[order]:
            dx, dy = Decimal(q[0]) - ax, Decimal(q[1]) - ay
            half = (dx * dx + dy * dy) / 2
            poly = _clip(poly, dx, dy, half)
        after = poly[1:] + poly[:1]
        area = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(poly, after, strict=True))
        tiny = Decimal(10) ** (10 - DIGITS)
        on_box = any(
            min(abs(x + ax - x0), abs(x + ax - x1), abs(y + ay - y0), abs(y + ay - y1)) < tiny
            for x, y in poly
        )
        radius = max((x * x + y * y).sqrt() for x, y in poly)
        return float(area / 2), on_box, float(radius)


def _clip(poly, dx, dy, half):
    """The polygon's part where x dx + y dy <= half."""
    side = [x * dx + y * dy - half for x, y in poly]
    if max(side) <= 0:
        return poly
    clipped = []
    for k, (p, sp) in enumerate(zip(poly, side, strict=True)):
        q, sq = poly[k - len(poly) + 1], side[k - len(poly) + 1]  # the next vertex
        if sp <= 0:
            clipped.append(p)
        if (sp < 0 < sq) or (sq < 0 < sp):
            t = sp / (sp - sq)
            clipped.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
    return clipped
