"""SampleSets: the one host type for a batch of pixels' sample sets, from the device read-back
(clrender.sampling.DeviceSampleSets.to_host) or a NumPy generator (clrender.sppp.draw_sppp) to
the estimators (clrender.estimators).

Positions are pixel-local, in W = [-1/2, 1/2]^2 (pixel (x, y) covers image coordinates
[x, x+1] x [y, y+1], so local (u, v) sits at (x + 1/2 + u, y + 1/2 + v)). Pixel p's traced
samples are traced[offsets[p]:offsets[p+1]]; its SPPP auxiliary nuclei (in the strip W' minus
W, never traced, they only shape Voronoi cells) are aux[aux_offsets[p]:aux_offsets[p+1]].
The values of the traced samples (radiance, or a test function) travel beside a SampleSets,
never inside it: one set of samples can be weighted by any estimator and any values.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from clrender.errors import ParameterError

# The array fields and the dtype a list given for them becomes.
ARRAY_FIELDS = {
    "traced": np.float64,
    "offsets": np.int64,
    "aux": np.float64,
    "aux_offsets": np.int64,
    "redraws": np.int64,
}


@dataclass(frozen=True)
class SampleSets:
    """Sample sets of P pixels in flat arrays.

    traced: (T, 2) float32 or float64, pixel by pixel; offsets: (P + 1,) rising from 0 to T;
    n: the sampler's intensity, the expected traced count per pixel (mc divides by it);
    aux, aux_offsets, eps: the SPPP auxiliary nuclei and the strip width (None without them);
    redraws: (P,) the redraw number each pixel was drawn with (None: all 0).
    """

    traced: np.ndarray
    offsets: np.ndarray
    n: float
    aux: np.ndarray | None = None
    aux_offsets: np.ndarray | None = None
    eps: float | None = None
    redraws: np.ndarray | None = None

    def __post_init__(self) -> None:
        """Array-likes (lists, tuples) become NumPy arrays; what cannot is a ParameterError.
        Shapes and values are checked where the sets are used (clrender.estimators.pixel)."""
        for name, dtype in ARRAY_FIELDS.items():
            value = getattr(self, name)
            if value is None or isinstance(value, np.ndarray):
                continue
            try:
                array = np.asarray(value, dtype=dtype)
            except (TypeError, ValueError) as err:
                raise ParameterError(
                    f"SampleSets.{name} must be an array of numbers, got {type(value).__name__}"
                    f" ({err})"
                ) from None
            object.__setattr__(self, name, array)
        for name in ("n", "eps"):
            value = getattr(self, name)
            if (value is not None or name == "n") and not isinstance(
                value, (int, float, np.number)
            ):
                raise ParameterError(
                    f"SampleSets.{name} must be a number, got {type(value).__name__}"
                )

    @property
    def pixel_count(self) -> int:
        return len(self.offsets) - 1

    @cached_property
    def counts(self) -> np.ndarray:
        """(P,) traced samples per pixel."""
        return np.diff(self.offsets)

    @cached_property
    def pixel_index(self) -> np.ndarray:
        """(T,) pixel of every traced sample."""
        return np.repeat(np.arange(self.pixel_count), self.counts)

    @property
    def has_aux(self) -> bool:
        """Whether the sets carry SPPP auxiliary nuclei (and their strip width)."""
        return self.aux is not None and self.aux_offsets is not None and self.eps is not None

    def subset(self, pixels: np.ndarray) -> SampleSets:
        """The sample sets of some pixels (in that order), renumbered 0 .. len(pixels) - 1."""
        pixels = np.asarray(pixels, np.int64)
        traced_index, offsets = segments(self.offsets, pixels)
        aux, aux_offsets = self.aux, self.aux_offsets
        if aux is not None and aux_offsets is not None:
            aux_index, aux_offsets = segments(aux_offsets, pixels)
            aux = aux[aux_index]
        redraws = None if self.redraws is None else self.redraws[pixels]
        return SampleSets(
            self.traced[traced_index], offsets, self.n, aux, aux_offsets, self.eps, redraws
        )


def segments(offsets: np.ndarray, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the concatenated segments offsets[p]:offsets[p+1] for p in pixels, and the
    offsets of those segments in the concatenation."""
    offsets = np.asarray(offsets, np.int64)
    starts = offsets[pixels]
    lengths = offsets[np.asarray(pixels) + 1] - starts
    new_offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    index = np.arange(new_offsets[-1]) - np.repeat(new_offsets[:-1] - starts, lengths)
    return index, new_offsets
