"""Tiles sized for the device's memory (clrender.pipeline.fit_tiles_to_device): the memory
model against the runtime pool's measured peaks, tiles lowered for a small device without
changing a pixel, and a one-line refusal when one pixel alone does not fit."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from clrender import pipeline
from clrender.api import radiance_source
from clrender.errors import ParameterError
from clrender.estimators.image_device import CHUNK_NUCLEI
from clrender.runtime import Runtime
from clrender.sampling import make_sampler


def small_device(global_mib: float, largest_mib: float, like) -> SimpleNamespace:
    """A device with the given memory, named like a real one."""
    return SimpleNamespace(
        global_mem_size=int(global_mib * 2**20),
        max_mem_alloc_size=int(largest_mib * 2**20),
        name=like.name,
        platform=like.platform,
        version=like.version,
    )


@pytest.mark.parametrize(
    "sampler, estimators",
    [
        ("independent", ["mc"]),
        ("sppp", ["vor_sn", "fvor", "mc_n"]),
        ("stratified", ["pvor"]),
        ("independent", ["cvor"]),
        ("sppp", ["ivor_sn"]),
    ],
)
def test_device_memory_stays_within_the_model(runtime, monkeypatch, sampler, estimators):
    # Every allocation goes through Runtime.allocate (the pool): its largest request and the
    # pool's peak over what it held before must stay within the model's bytes per tile
    # nucleus (plus, for the image-level cells, their launch of about CHUNK_NUCLEI nuclei)
    peak = {"largest": 0, "managed": 0}
    allocate = Runtime.allocate

    def recorded(self, nbytes):
        peak["largest"] = max(peak["largest"], int(nbytes))
        buffer = allocate(self, nbytes)
        peak["managed"] = max(peak["managed"], self.pool.managed_bytes)
        return buffer

    runtime.pool.free_held()
    before = runtime.pool.managed_bytes
    monkeypatch.setattr(Runtime, "allocate", recorded)
    settings = pipeline.RenderSettings(
        32, 32, make_sampler(sampler, 256), list(estimators), tile_samples=100_000
    )
    result = _render(runtime, settings)
    tile_nuclei = pipeline.pixels_per_tile(result.settings) * pipeline.tile_nuclei_per_pixel(
        result.settings
    )
    image_level = estimators == ["ivor_sn"]
    reserve = pipeline.IMAGE_CELLS_DEVICE_BYTES * CHUNK_NUCLEI if image_level else 0
    assert peak["managed"] - before <= pipeline.TILE_DEVICE_BYTES * tile_nuclei + reserve
    largest = pipeline.TILE_LARGEST_BUFFER_BYTES * tile_nuclei
    if image_level:
        largest = max(largest, pipeline.IMAGE_CELLS_LARGEST_BUFFER_BYTES * CHUNK_NUCLEI * 1.1)
    assert peak["largest"] <= largest


def test_a_small_device_gets_smaller_tiles_and_the_same_image(runtime, monkeypatch):
    settings = pipeline.RenderSettings(24, 20, make_sampler("sppp", 64), ["vor_sn", "mc_n"])
    whole = _render(runtime, settings)
    fit = pipeline.fit_tiles_to_device
    used = []

    def on_a_small_device(settings, device):
        fitted = fit(settings, small_device(2, 0.25, device))
        used.append(fitted.tile_samples)
        return fitted

    monkeypatch.setattr(pipeline, "fit_tiles_to_device", on_a_small_device)
    small = _render(runtime, settings)
    # 2 MiB of global memory, half of it for tiles: 14563 nuclei at 72 B (buffers of 0.25 MiB
    # would hold 21845 at 12 B)
    assert used == [2**20 // pipeline.TILE_DEVICE_BYTES]
    assert small.stats.tiles > whole.stats.tiles
    for name in ("vor_sn", "mc_n"):
        np.testing.assert_array_equal(small.images[name], whole.images[name])


def test_one_pixel_too_large_for_the_device_is_refused_in_one_line(runtime):
    settings = pipeline.RenderSettings(4, 4, make_sampler("independent", 40_000), "mc")
    device = runtime.device
    # 40 000 samples a pixel: a 469 KiB radiance buffer, 2.4 MiB in all
    assert pipeline.fit_tiles_to_device(settings, small_device(8, 1, device)) is not None
    for global_mib, largest_mib in ((4, 1), (8, 0.25)):
        with pytest.raises(ParameterError) as error:
            pipeline.fit_tiles_to_device(settings, small_device(global_mib, largest_mib, device))
        message = str(error.value)
        assert "\n" not in message and "use fewer samples per pixel" in message
        assert device.name.strip() in message
    # The image-level cells hold a pixel's neighbourhood: refused where the tiles alone fit
    sppp = replace(settings, sampler=make_sampler("sppp", 40_000), estimator=["ivor_sn"])
    assert pipeline.fit_tiles_to_device(
        replace(sppp, estimator=["mc_n"]), small_device(64, 2, device)
    )
    with pytest.raises(ParameterError, match="fewer samples per pixel"):
        pipeline.fit_tiles_to_device(sppp, small_device(64, 2, device))


def test_the_default_tiles_fit_a_small_gpu_unchanged(runtime):
    # A 1 GiB device with allocations up to 256 MiB (OpenCL guarantees a quarter of the global
    # memory) runs the default tiles (4 M nuclei) of every estimator family as they are
    device = small_device(1024, 256, runtime.device)
    for sampler, estimators in (("independent", ["mc"]), ("sppp", ["vor_sn", "fvor", "ivor_sn"])):
        settings = pipeline.RenderSettings(256, 256, make_sampler(sampler, 256), estimators)
        assert pipeline.fit_tiles_to_device(settings, device) is settings


def _render(runtime, settings):
    """An analytic image (no paths to trace) rendered with the settings."""
    size = (settings.width, settings.height)
    return pipeline.render(runtime, radiance_source(runtime, "analytic:mix", size, 8), settings)
