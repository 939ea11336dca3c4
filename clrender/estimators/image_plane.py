"""Plane pixels for the image-level estimators (clrender.estimators.image): rectangles of
pixels, the RNG keys of pixels inside and outside the image, unique point ids, and the nuclei
of a rectangle sorted by pixel.

"Plane pixels" are all integer (x, y), inside the image or not; pixel (x, y) covers image
coordinates [x, x+1] x [y, y+1].

Image border. The guard band reaches beyond the image; its pixels need RNG keys:
- "frame" (default): the plane outside the image is more of the same Poisson process. Plane
  pixel (x, y) outside the image in ring k = max(-x, x - W + 1, -y, y - H + 1) >= 1 gets
  the key W H + (k - 1)(2 W + 2 H + 4 k - 4) + (its place on ring k: top row left to right,
  bottom row, left column top to bottom, right column). The keys of a ring do not depend on how
  many rings are drawn. Border pixels are then estimated exactly like interior ones.
- "periodic": the image is a torus; plane pixel (x, y) takes the key of (x mod W, y mod H)
  (its nuclei are copies, shifted). Also exactly unbiased (E[v] = 1/n on a torus), but it
  correlates the errors of opposite border pixels, so "frame" is the default.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from clrender.errors import ParameterError
from clrender.samples import SampleSets

BORDERS = ("frame", "periodic")
DEFAULT_BORDER = "frame"
# Unique point ids: plane pixel (x, y) and sample s -> ((y + ID_OFFSET) 2^16 + x + ID_OFFSET)
# 2^30 + s, for |x|, |y| < 2^15 and s < 2^30.
ID_OFFSET = 1 << 15
SAMPLE_BITS = 30


# ---------------------------------------------------------------------------------------------
# Pixel rectangles and RNG keys


@dataclass(frozen=True)
class PixelRect:
    """Plane pixels [x0, x1) x [y0, y1), row-major."""

    x0: int
    y0: int
    x1: int
    y1: int

    @property
    def width(self) -> int:
        return self.x1 - self.x0

    @property
    def height(self) -> int:
        return self.y1 - self.y0

    @property
    def count(self) -> int:
        return self.width * self.height

    def grown(self, ring: int) -> PixelRect:
        return PixelRect(self.x0 - ring, self.y0 - ring, self.x1 + ring, self.y1 + ring)

    def coords(self) -> tuple[np.ndarray, np.ndarray]:
        ys, xs = np.mgrid[self.y0 : self.y1, self.x0 : self.x1]
        return xs.ravel(), ys.ravel()

    def contains(self, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        return (xs >= self.x0) & (xs < self.x1) & (ys >= self.y0) & (ys < self.y1)


def frame_keys(xs: np.ndarray, ys: np.ndarray, width: int, height: int) -> np.ndarray:
    """RNG pixel keys of plane pixels for the "frame" border (module docstring)."""
    xs, ys = np.asarray(xs, np.int64), np.asarray(ys, np.int64)
    ring = np.maximum.reduce([-xs, xs - width + 1, -ys, ys - height + 1, np.zeros_like(xs)])
    k = np.maximum(ring, 1)
    side = width + 2 * k  # length of ring k's top and bottom rows
    top, bottom = ys == -k, ys == height - 1 + k
    left = ~top & ~bottom & (xs == -k)
    place = np.where(
        top,
        xs + k,
        np.where(
            bottom,
            side + xs + k,
            np.where(left, 2 * side + ys + k - 1, 2 * side + height + 2 * k - 2 + ys + k - 1),
        ),
    )
    outside = width * height + (k - 1) * (2 * width + 2 * height + 4 * k - 4) + place
    keys = np.where(ring > 0, outside, ys * width + xs)
    if len(keys) and keys.max() >= 2**32:
        raise ParameterError("frame keys overflow 32 bits: image or guard band too large")
    return keys.astype(np.uint32)


def periodic_keys(xs: np.ndarray, ys: np.ndarray, width: int, height: int) -> np.ndarray:
    """RNG pixel keys of plane pixels for the "periodic" border: the image pixel (x mod W,
    y mod H)."""
    xs, ys = np.asarray(xs, np.int64), np.asarray(ys, np.int64)
    return (np.mod(ys, height) * width + np.mod(xs, width)).astype(np.uint32)


def pixel_keys(xs, ys, width: int, height: int, border: str) -> np.ndarray:
    check_border(border)
    keys = frame_keys if border == "frame" else periodic_keys
    return keys(xs, ys, width, height)


def check_border(border: str) -> None:
    if border not in BORDERS:
        raise ParameterError(f"unknown border {border!r}; accepted: {', '.join(BORDERS)}")


def point_ids(xs: np.ndarray, ys: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Unique ids of the nuclei of plane pixels (xs, ys), counts[i] nuclei each, in order."""
    counts = np.asarray(counts, np.int64)
    if (np.abs(xs) >= ID_OFFSET).any() or (np.abs(ys) >= ID_OFFSET).any():
        raise ParameterError(f"plane pixel coordinates must stay below {ID_OFFSET} in size")
    pixel_id = (np.asarray(ys, np.int64) + ID_OFFSET) * (2 * ID_OFFSET) + xs + ID_OFFSET
    starts = np.cumsum(counts) - counts
    sample = np.arange(counts.sum()) - np.repeat(starts, counts)
    return (np.repeat(pixel_id, counts) << SAMPLE_BITS) + sample


# ---------------------------------------------------------------------------------------------
# Point grids: nuclei of a rectangle of plane pixels, sorted by pixel


@dataclass
class PixelPoints:
    """Nuclei of a list of plane pixels, pixel by pixel: positions in image coordinates."""

    positions: np.ndarray  # (M, 2) float64
    counts: np.ndarray  # (len(pixels),) int64
    ids: np.ndarray  # (M,) int64, unique
    values: np.ndarray  # (M,) or (M, C) float64; meaningful for traced pixels only


# A source of nuclei: (xs, ys) plane pixels -> their PixelPoints, in that order.
PointSource = Callable[[np.ndarray, np.ndarray], PixelPoints]


@dataclass
class PointGrid:
    """The nuclei of every pixel of `rect`, row-major by pixel (offsets has rect.count + 1
    entries). Pixels outside rect have no nuclei as far as take() is concerned."""

    rect: PixelRect
    positions: np.ndarray
    offsets: np.ndarray
    ids: np.ndarray
    values: np.ndarray

    def take(self, xs: np.ndarray, ys: np.ndarray) -> PixelPoints:
        inside = self.rect.contains(xs, ys)
        cell = (ys - self.rect.y0) * self.rect.width + (xs - self.rect.x0)
        cell = np.where(inside, cell, 0)
        starts = self.offsets[cell]
        counts = np.where(inside, self.offsets[cell + 1] - starts, 0)
        index = _segment_index(starts, counts)
        return PixelPoints(self.positions[index], counts, self.ids[index], self.values[index])


def _segment_index(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Indices start[i] .. start[i] + counts[i] - 1, concatenated."""
    ends = np.cumsum(counts)
    return np.arange(ends[-1] if len(ends) else 0) - np.repeat(ends - counts - starts, counts)


def grid_from_points(
    rect: PixelRect, positions: np.ndarray, values: np.ndarray, ids: np.ndarray
) -> PointGrid:
    """Sort image-coordinate nuclei into the pixels of rect (nuclei outside rect dropped)."""
    px = np.floor(positions[:, 0]).astype(np.int64)
    py = np.floor(positions[:, 1]).astype(np.int64)
    keep = rect.contains(px, py)
    cell = (py - rect.y0) * rect.width + (px - rect.x0)
    order = np.flatnonzero(keep)[np.argsort(cell[keep], kind="stable")]
    counts = np.bincount(cell[order], minlength=rect.count)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    return PointGrid(rect, positions[order], offsets, ids[order], values[order])


# ---------------------------------------------------------------------------------------------
# A render tile's nuclei: its traced samples, guard nuclei regenerated on the device


def tile_point_source(
    runtime,
    config,
    seed: int,
    width: int,
    height: int,
    pixels: np.ndarray,
    samples: SampleSets,
    values: np.ndarray,
    ring: int,
    border: str = DEFAULT_BORDER,
) -> PointSource:
    """A PointSource for a render tile: the tile's traced samples (its sample sets, one
    value per traced sample) plus the nuclei of every plane pixel within `ring` pixels
    of it, drawn with generate_sample_sets under the border's keys (positions only, no
    auxiliary nuclei). Pixels beyond that ring are generated on demand (guard fallback)."""
    from clrender.sampling import generate_sample_sets

    guard_config = replace(config, n_aux=0)

    def generate(xs: np.ndarray, ys: np.ndarray) -> PixelPoints:
        keys = pixel_keys(xs, ys, width, height, border)
        sets = generate_sample_sets(runtime, guard_config, seed, keys).to_host(runtime.queue)
        counts = sets.counts.astype(np.int64)
        shift = np.repeat(np.column_stack([xs, ys]) + 0.5, counts, axis=0)
        zeros = np.zeros((len(sets.traced),) + values.shape[1:])
        return PixelPoints(
            sets.traced.astype(np.float64) + shift, counts, point_ids(xs, ys, counts), zeros
        )

    grid = _tile_grid(pixels, samples, values, width, ring, generate)

    def source(xs: np.ndarray, ys: np.ndarray) -> PixelPoints:
        if grid.rect.contains(xs, ys).all():
            return grid.take(xs, ys)
        return generate(xs, ys)

    return source


def _tile_grid(pixels, samples: SampleSets, values, width, ring, generate) -> PointGrid:
    """The tile's rows grown by `ring`: traced samples of the tile, generated guard nuclei."""
    ty, tx = np.divmod(np.asarray(pixels, np.int64), width)
    rect = PixelRect(int(tx.min()), int(ty.min()), int(tx.max()) + 1, int(ty.max()) + 1).grown(ring)
    xs, ys = rect.coords()
    in_tile = np.zeros(rect.count, bool)
    in_tile[(ty - rect.y0) * rect.width + tx - rect.x0] = True
    guard = generate(xs[~in_tile], ys[~in_tile])
    counts = samples.counts.astype(np.int64)
    own = samples.traced.astype(np.float64) + np.repeat(
        np.column_stack([tx, ty]) + 0.5, counts, axis=0
    )
    positions = np.concatenate([own, guard.positions])
    cell = np.concatenate(
        [
            np.repeat((ty - rect.y0) * rect.width + tx - rect.x0, counts),
            np.repeat(np.flatnonzero(~in_tile), guard.counts),
        ]
    )
    order = np.argsort(cell, kind="stable")
    all_counts = np.zeros(rect.count, np.int64)
    all_counts[in_tile] = counts[np.argsort((ty - rect.y0) * rect.width + tx - rect.x0)]
    all_counts[~in_tile] = guard.counts
    ids = np.concatenate([point_ids(tx, ty, counts), guard.ids])
    vals = np.concatenate([np.asarray(values, np.float64), guard.values])
    return PointGrid(
        rect,
        positions[order],
        np.concatenate([[0], np.cumsum(all_counts)]),
        ids[order],
        vals[order],
    )
