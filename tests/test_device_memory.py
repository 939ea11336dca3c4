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
    "sampler, spp, estimators",
    [
        ("independent", 256, ["mc"]),
        ("independent", 1, ["mc"]),  # the per-pixel buffers weigh most
        ("sobol", 2, ["mc", "mc_n"]),
        ("sppp", 256, ["vor_sn", "fvor", "mc_n"]),
        ("sppp", 64, ["vor_sn", "fvor", "mc_n", "cvor", "pvor"]),  # every kind of cells at once
        ("stratified", 1, ["pvor"]),
        ("independent", 1, ["cvor"]),
        ("sppp", 256, ["ivor_sn"]),
    ],
)
def test_device_memory_stays_within_the_model(runtime, monkeypatch, sampler, spp, estimators):
    # Every allocation goes through Runtime.allocate (the pool): its largest request and the
    # pool's peak over what it held before must stay within the model (tile_device_bytes and
    # the image-level cells' launch)
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
        32, 32, make_sampler(sampler, spp), list(estimators), tile_samples=100_000
    )
    _render(runtime, settings)
    tile_largest, tile_held = pipeline.tile_device_bytes(
        settings, pipeline.pixels_per_tile(settings)
    )
    cells_largest, cells_held = pipeline.image_cells_device_bytes(settings)
    assert peak["managed"] - before <= tile_held + cells_held
    # The image-level launch takes about CHUNK_NUCLEI nuclei (Poisson: within 10 %)
    launch_largest = cells_largest and pipeline.IMAGE_CELLS_NUCLEUS_BYTES[0] * CHUNK_NUCLEI * 1.1
    assert peak["largest"] <= max(tile_largest, launch_largest)


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
    # 2 MiB of global memory, half of it for tiles at 160 B a nucleus and 512 B a pixel (its
    # buffers of 0.25 MiB hold more pixels at 12 B a nucleus)
    per_pixel = pipeline.tile_nuclei_per_pixel(settings)
    assert used == [2**20 // (160 * per_pixel + 512) * per_pixel]
    assert small.stats.tiles > whole.stats.tiles
    # The result reports the tiles it ran with
    assert small.settings.tile_samples == used[0] < whole.settings.tile_samples
    for name in ("vor_sn", "mc_n"):
        np.testing.assert_array_equal(small.images[name], whole.images[name])


def test_one_pixel_too_large_for_the_device_is_refused_in_one_line(runtime):
    settings = pipeline.RenderSettings(4, 4, make_sampler("independent", 40_000), "mc")
    device = runtime.device
    # 40 000 samples a pixel: a 469 KiB radiance buffer, 6.1 MiB in all
    assert pipeline.fit_tiles_to_device(settings, small_device(16, 1, device)) is not None
    for global_mib, largest_mib in ((8, 1), (16, 0.25)):
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
