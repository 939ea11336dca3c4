"""Analytic images: radiance functions of image position with exact pixel integrals.

They stand in for the path tracer in tests and benchmarks: every estimator's output can be
compared with the true integral of each pixel. Image coordinates: pixel (x, y) covers
[x, x+1] x [y, y+1], row 0 at the top; a sample at pixel-local (u, v) in [-1/2, 1/2]^2 sits at
(x + 1/2 + u, y + 1/2 + v).

  edge    a tilted straight step edge (discontinuous; exact integrals in closed form)
  smooth  a separable product of sines, wavelengths of a few pixels (closed form)
  disc    the indicator of a disc (integrals of boundary pixels by adaptive quadrature, 1e-13)
  bowl    a paraboloid repeated in every pixel, 0 at pixel centres and 1/2 at corners
          (continuous and pixel-periodic: exactly what clipped Voronoi cells get wrong)
  mix     edge, smooth and disc in the red, green and blue channels

Scene names: `analytic` (= analytic:mix) and `analytic:KIND` for each kind above.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import pyopencl as cl

from clrender.errors import ParameterError
from clrender.radiance import DeviceRadiance, SampleRadiance
from clrender.runtime import Runtime
from clrender.sampling import DeviceSampleSets

ANALYTIC_PREFIX = "analytic"
ANALYTIC_KINDS = ("edge", "smooth", "disc", "bowl", "mix")
DEFAULT_RESOLUTION = (64, 64)


class AnalyticFunction(Protocol):
    def value(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """f at image positions (float64 arrays of the same shape)."""
        ...

    def pixel_integrals(self, width: int, height: int) -> np.ndarray:
        """(height, width) exact integrals of f over each pixel (|pixel| = 1)."""
        ...


def clamp_antiderivative(t: np.ndarray) -> np.ndarray:
    """G with G' = clamp(t, 0, 1) and G(t) = 0 for t <= 0."""
    return np.where(t <= 0.0, 0.0, np.where(t >= 1.0, t - 0.5, 0.5 * t * t))


@dataclass(frozen=True)
class StepEdge:
    """`inside` where x < x0 + slope * (y - y0) (left of a tilted line), `outside` elsewhere."""

    x0: float
    y0: float
    slope: float
    inside: float = 1.0
    outside: float = 0.1

    def value(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        left = x < self.x0 + self.slope * (y - self.y0)
        return np.where(left, self.inside, self.outside)

    def pixel_integrals(self, width: int, height: int) -> np.ndarray:
        ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
        # Covered length of the row at height t: clamp(a + slope * t, 0, 1), integrated over t.
        a = self.x0 - self.slope * self.y0 - xs
        if self.slope == 0.0:
            covered = np.clip(a, 0.0, 1.0)
        else:
            top = clamp_antiderivative(a + self.slope * (ys + 1.0))
            covered = (top - clamp_antiderivative(a + self.slope * ys)) / self.slope
        return self.outside + (self.inside - self.outside) * covered


@dataclass(frozen=True)
class SmoothSines:
    """base + amplitude * sin(kx x + px) * sin(ky y + py): smooth, curved at the pixel scale."""

    kx: float
    ky: float
    px: float = 0.3
    py: float = 1.1
    base: float = 0.5
    amplitude: float = 0.4

    def value(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self.base + self.amplitude * np.sin(self.kx * x + self.px) * np.sin(
            self.ky * y + self.py
        )

    def pixel_integrals(self, width: int, height: int) -> np.ndarray:
        def sine_integral(k: float, phase: float, count: int) -> np.ndarray:
            lo = np.arange(count, dtype=np.float64)
            return (np.cos(k * lo + phase) - np.cos(k * (lo + 1.0) + phase)) / k

        sx = sine_integral(self.kx, self.px, width)
        sy = sine_integral(self.ky, self.py, height)
        return self.base + self.amplitude * np.outer(sy, sx)


@dataclass(frozen=True)
class Disc:
    """`inside` on the closed disc of centre (cx, cy) and radius r, `outside` elsewhere."""

    cx: float
    cy: float
    r: float
    inside: float = 0.9
    outside: float = 0.05

    def value(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        in_disc = (x - self.cx) ** 2 + (y - self.cy) ** 2 <= self.r * self.r
        return np.where(in_disc, self.inside, self.outside)

    def pixel_integrals(self, width: int, height: int) -> np.ndarray:
        ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
        # Nearest and farthest points of each pixel from the centre decide the easy pixels.
        near_x = np.clip(self.cx, xs, xs + 1.0) - self.cx
        near_y = np.clip(self.cy, ys, ys + 1.0) - self.cy
        far_x = np.maximum(abs(xs - self.cx), abs(xs + 1.0 - self.cx))
        far_y = np.maximum(abs(ys - self.cy), abs(ys + 1.0 - self.cy))
        covered = (far_x**2 + far_y**2 <= self.r**2).astype(np.float64)
        boundary = (near_x**2 + near_y**2 < self.r**2) & (covered == 0.0)
        # A loop over the boundary pixels only (about 2 pi r of them): reference values.
        for y, x in zip(*np.nonzero(boundary), strict=True):
            covered[y, x] = self.covered_area(float(x), float(y))
        return self.outside + (self.inside - self.outside) * covered

    def covered_area(self, x: float, y: float) -> float:
        """Area of the disc inside [x, x+1] x [y, y+1]: a 1-D integral of the chord length,
        split where the integrand has kinks so quad converges to ~1e-13."""
        from scipy.integrate import quad  # here: scipy.integrate takes ~0.1 s to import

        def half_chord(t: float) -> float:
            return math.sqrt(max(self.r * self.r - (t - self.cx) ** 2, 0.0))

        def half_chord_at(e: float) -> float:
            return math.sqrt(self.r * self.r - (e - self.cy) ** 2)

        def covered_height(t: float) -> float:
            h = half_chord(t)
            return max(0.0, min(y + 1.0, self.cy + h) - max(y, self.cy - h))

        lo, hi = max(x, self.cx - self.r), min(x + 1.0, self.cx + self.r)
        if hi <= lo:
            return 0.0
        # Where the circle crosses the pixel's top and bottom edges.
        crossings = [e for e in (y, y + 1.0) if abs(e - self.cy) < self.r]
        kinks = [self.cx + s * half_chord_at(e) for e in crossings for s in (-1.0, 1.0)]
        cuts = sorted({lo, hi, *(k for k in kinks if lo < k < hi)})
        return sum(
            quad(covered_height, a, b, epsabs=1e-14, epsrel=1e-13, limit=200)[0]
            for a, b in zip(cuts[:-1], cuts[1:], strict=True)
        )


@dataclass(frozen=True)
class PixelBowl:
    """(u^2 + v^2) scaled, with (u, v) the position relative to the pixel centre: the same
    bowl in every pixel, integral scale / 6 over each."""

    scale: float = 1.0

    def value(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        u = x - np.floor(x) - 0.5
        v = y - np.floor(y) - 0.5
        return self.scale * (u * u + v * v)

    def pixel_integrals(self, width: int, height: int) -> np.ndarray:
        return np.full((height, width), self.scale / 6.0)


@dataclass(frozen=True)
class AnalyticImage:
    """Three analytic functions, one per RGB channel."""

    name: str
    channels: tuple[AnalyticFunction, AnalyticFunction, AnalyticFunction]

    def radiance(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(len(x), 3) float32 radiance at image positions."""
        return np.stack([f.value(x, y) for f in self.channels], axis=-1).astype(np.float32)

    def pixel_integrals(self, width: int, height: int) -> np.ndarray:
        """(height, width, 3) float64 exact pixel integrals."""
        return np.stack([f.pixel_integrals(width, height) for f in self.channels], axis=-1)


def analytic_functions(width: int, height: int) -> dict[str, AnalyticFunction]:
    """The named functions, laid out relative to the image size."""
    size = min(width, height)
    return {
        "edge": StepEdge(x0=0.5 * width + 0.137, y0=0.5 * height, slope=0.364),
        "smooth": SmoothSines(kx=2.0 * math.pi / 3.7, ky=2.0 * math.pi / 5.3),
        "disc": Disc(cx=0.45 * width + 0.21, cy=0.55 * height - 0.33, r=0.3 * size + 0.17),
        "bowl": PixelBowl(),
    }


def is_analytic_scene(name: str) -> bool:
    return name == ANALYTIC_PREFIX or name.startswith(ANALYTIC_PREFIX + ":")


def analytic_image(name: str, width: int, height: int) -> AnalyticImage:
    """The analytic image for a scene name `analytic[:edge|smooth|disc|mix]`."""
    kind = name.partition(":")[2] or "mix"
    functions = analytic_functions(width, height)
    if kind == "mix":
        channels = (functions["edge"], functions["smooth"], functions["disc"])
    elif kind in functions:
        channels = (functions[kind],) * 3
    else:
        accepted = ", ".join(f"{ANALYTIC_PREFIX}:{k}" for k in ANALYTIC_KINDS)
        raise ParameterError(f"unknown analytic scene {name!r}; accepted: {accepted}")
    return AnalyticImage(f"{ANALYTIC_PREFIX}:{kind}", channels)


def sample_image_positions(
    pixels: np.ndarray, offsets: np.ndarray, local: np.ndarray, image_width: int
) -> tuple[np.ndarray, np.ndarray]:
    """Image positions (float64) of pixel-local samples; pixel p owns local[offsets[p]:...]."""
    owner = np.repeat(np.asarray(pixels, np.int64), np.diff(offsets))
    x = (owner % image_width).astype(np.float64) + 0.5 + local[:, 0].astype(np.float64)
    y = (owner // image_width).astype(np.float64) + 0.5 + local[:, 1].astype(np.float64)
    return x, y


@dataclass
class PendingAnalytic:
    image: AnalyticImage
    sample_sets: DeviceSampleSets
    queue: cl.CommandQueue
    width: int

    def to_host(self) -> SampleRadiance:
        sets = self.sample_sets
        host = sets.to_host(self.queue)
        x, y = sample_image_positions(sets.pixels, host.offsets, host.traced, self.width)
        return SampleRadiance(self.image.radiance(x, y), ray_count=0)

    def queue_to_host(self) -> Callable[[], SampleRadiance]:
        """Evaluated on the host now (it waits for the sample sets)."""
        radiance = self.to_host()
        return lambda: radiance

    def to_device(self, runtime: Runtime) -> DeviceRadiance:
        """Evaluated on the host, then uploaded as float32."""
        values = self.to_host().values
        return DeviceRadiance(runtime.upload(np.asarray(values, np.float32)), ray_count=0)


@dataclass
class AnalyticSource:
    """A RadianceSource evaluating an analytic image at each traced sample (on the host)."""

    image: AnalyticImage
    queue: cl.CommandQueue
    width: int
    height: int

    @classmethod
    def for_scene(cls, name: str, queue: cl.CommandQueue, width: int, height: int):
        return cls(analytic_image(name, width, height), queue, width, height)

    @property
    def description(self) -> str:
        return self.image.name

    def pixel_integrals(self) -> np.ndarray:
        """(height, width, 3) exact pixel integrals of the image this source renders."""
        return self.image.pixel_integrals(self.width, self.height)

    def trace(self, sample_sets: DeviceSampleSets, seed: int) -> PendingAnalytic:
        return PendingAnalytic(self.image, sample_sets, self.queue, self.width)
