"""Radiance sources: what the pipeline asks for the radiance of each traced sample.

A source takes a launch's sample sets (on the device) and returns a pending result; the
pipeline collects it with `to_host()` once it needs the values, so a source backed by an
OpenCL kernel runs while the host does other work. Two sources exist: the path tracer
(`PathTracerSource`, clrender.trace) and closed-form images of known pixel integrals
(`AnalyticSource`, clrender.analytic) used to check the estimators end to end.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from clrender.runtime import Runtime
from clrender.sampling import DeviceSampleSets
from clrender.trace import PathTracer, TraceResult


@dataclass
class SampleRadiance:
    """Radiance of a launch's traced samples, in sample order, with the launch's counts."""

    values: np.ndarray  # (T, 3) float32
    ray_count: int  # rays cast (0 for analytic sources)
    device_nonfinite: int = 0  # non-finite samples the source counted (and may have zeroed)


class DeviceRadiance:
    """Radiance of a launch's traced samples left on the device: a (T, 3) float32 buffer, with
    the launch's counts, or a function that reads them when first asked (a tracer's counters:
    read then, so that handing the buffer on does not wait for the trace)."""

    def __init__(
        self,
        buffer,
        ray_count: int = 0,
        device_nonfinite: int = 0,
        counts: Callable[[], tuple[int, int]] | None = None,
    ):
        self.buffer = buffer  # a pyopencl buffer
        self._counts = (ray_count, device_nonfinite) if counts is None else None
        self._read_counts = counts

    def _resolved(self) -> tuple[int, int]:
        if self._counts is None:
            self._counts = self._read_counts()
        return self._counts

    @property
    def ray_count(self) -> int:
        return self._resolved()[0]

    @property
    def device_nonfinite(self) -> int:
        return self._resolved()[1]


class PendingRadiance(Protocol):
    def to_host(self) -> SampleRadiance:
        """Wait for the source's work and return the radiance on the host."""
        ...

    def to_device(self, runtime: Runtime) -> DeviceRadiance:
        """The radiance as a device buffer of `runtime` (no copy if it is already there)."""
        ...

    def queue_to_host(self) -> Callable[[], SampleRadiance]:
        """Queue what to_host reads without waiting for it (a source computed on the host may
        compute it now); the function returned waits for it and gives to_host's result."""
        ...


class RadianceSource(Protocol):
    """Anything that turns sample positions into radiance values, for one image size."""

    description: str
    width: int
    height: int

    def trace(self, sample_sets: DeviceSampleSets, seed: int) -> PendingRadiance:
        """Start computing the radiance of every traced sample of `sample_sets` (pixel
        indices y * width + x)."""
        ...


@dataclass
class PendingTrace:
    result: TraceResult

    def to_host(self) -> SampleRadiance:
        return self.queue_to_host()()

    def queue_to_host(self) -> Callable[[], SampleRadiance]:
        result = self.result
        values = result.queue_to_host()
        return lambda: SampleRadiance(values(), result.rays, result.nonfinite)

    def to_device(self, runtime: Runtime) -> DeviceRadiance:
        result = self.result
        result.enqueue_counter_read()
        return DeviceRadiance(result.radiance, counts=lambda: (result.rays, result.nonfinite))


@dataclass
class PathTracerSource:
    """The path tracer as a radiance source (it zeroes non-finite radiance on the device and
    only counts it)."""

    tracer: PathTracer
    width: int
    height: int
    description: str = "path tracer"

    def trace(self, sample_sets: DeviceSampleSets, seed: int) -> PendingTrace:
        return PendingTrace(self.tracer.trace(sample_sets, seed, self.width, self.height))
