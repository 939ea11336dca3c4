"""The film: one RGB estimate per pixel, with which pixels are done and which were flagged.

A render of several estimators has one film per estimator and one set of per-pixel layers
(PixelLayers), shared because every estimator of a pixel uses the same accepted draw: its
traced sample count, its redraw number and the variance layer (clrender.estimators.variance).

Pixels are addressed by their global index y * width + x (row 0 at the top). A pixel is
*flagged* when its estimate could not be trusted: one of its samples had a non-finite radiance
(NaN or Inf), or the estimator returned a non-finite value. A flagged pixel holds the defined
value FLAGGED_VALUE (black) rather than a NaN, and the film counts it, so the closing summary
and the EXR metadata report it instead of a NaN sitting silently in the image. Pixels never
rendered (an interrupted render) hold UNRENDERED_VALUE (black) and are not counted as rendered.
"""

from __future__ import annotations

import os

import numpy as np

from clrender.errors import ParameterError

FLAGGED_VALUE = 0.0
UNRENDERED_VALUE = 0.0
# Host bytes a pixel takes from render to written files: the film (float32 RGB and two flags),
# the image handed to the writers, its EXR read-back check, the PNG's bytes and rows.
HOST_BYTES_PER_PIXEL = 12 + 2 + 12 + 12 + 7
# ... and the layers (samples, redraws, RGB variance: 20 B), their EXR channels as written and
# read back (2 x 24 B) and the flags as a uint32 channel, once per render
LAYER_BYTES_PER_PIXEL = 20 + 2 * 24 + 4


def physical_memory() -> int | None:
    """This machine's physical memory in bytes (None where the OS does not say)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_image_memory(
    width: int, height: int, memory: int | None = None, estimators: int = 1
) -> None:
    """ParameterError, before any work, if the images alone (one per estimator, and the layers
    and their written copy) need more host memory than the machine has (the render would fail
    deep inside an allocation)."""
    memory = physical_memory() if memory is None else memory
    per_pixel = HOST_BYTES_PER_PIXEL * estimators + LAYER_BYTES_PER_PIXEL
    need = width * height * per_pixel
    if memory is not None and need > memory:
        raise ParameterError(
            f"a {width}x{height} image needs about {need / 2**30:.1f} GiB of host memory "
            f"({per_pixel} bytes a pixel), more than this machine's "
            f"{memory / 2**30:.1f} GiB: render it at a lower resolution"
        )


class Film:
    def __init__(self, width: int, height: int):
        self.width = width
        self.height = height
        self.pixels = np.full((width * height, 3), UNRENDERED_VALUE, np.float32)
        self.rendered = np.zeros(width * height, bool)
        self.flagged = np.zeros(width * height, bool)

    @property
    def pixel_count(self) -> int:
        return self.width * self.height

    @property
    def rendered_count(self) -> int:
        return int(np.count_nonzero(self.rendered))

    @property
    def flagged_count(self) -> int:
        return int(np.count_nonzero(self.flagged))

    @property
    def complete(self) -> bool:
        return bool(self.rendered.all())

    def record(self, pixels: np.ndarray, estimates: np.ndarray, flagged: np.ndarray) -> None:
        """Store the (P, 3) estimates of global pixels; flagged ones, or any with a
        non-finite estimate, get FLAGGED_VALUE and are marked flagged."""
        estimates = np.asarray(estimates, np.float64).reshape(len(pixels), 3)
        bad = np.asarray(flagged, bool) | ~np.isfinite(estimates).all(axis=1)
        self.pixels[pixels] = np.where(bad[:, None], FLAGGED_VALUE, estimates)
        self.flagged[pixels] = bad
        self.rendered[pixels] = True

    def image(self) -> np.ndarray:
        """(height, width, 3) float32 linear RGB, row 0 at the top."""
        return self.pixels.reshape(self.height, self.width, 3)


class PixelLayers:
    """Per-pixel layers beside the estimates: traced samples N of the accepted draw, its redraw
    number (0: the first draw was accepted) and the mc variance estimate (RGB; NaN where the
    sampler's form is undefined, see clrender.estimators.variance)."""

    def __init__(self, width: int, height: int):
        self.width = width
        self.height = height
        self.samples = np.zeros(width * height, np.uint32)
        self.redraws = np.zeros(width * height, np.uint32)
        self.variance = np.zeros((width * height, 3), np.float32)

    def record(
        self, pixels: np.ndarray, counts: np.ndarray, redraws: np.ndarray, variance: np.ndarray
    ) -> None:
        self.samples[pixels] = counts
        self.redraws[pixels] = redraws
        self.variance[pixels] = variance

    def images(self) -> dict[str, np.ndarray]:
        """name -> (height, width) or (height, width, 3) array, row 0 at the top."""
        shape = (self.height, self.width)
        return {
            "samples": self.samples.reshape(shape),
            "redraws": self.redraws.reshape(shape),
            "mc_variance": self.variance.reshape(shape + (3,)),
        }
