"""The SIMD-across-paths research prototype (kernels/simd_paths_probe.cl, bench/simd_paths_probe.py)
traces the megakernel's paths: the same radiance to the bit, sample for sample."""

import sys
from pathlib import Path

import numpy as np
import pytest

from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import load_scene
from clrender.trace import PathTracer

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from simd_paths_probe import Prototype, check_scene  # noqa: E402

SIZE = 24
SPP = 3  # 24 * 24 * 3 samples: not a multiple of the work-items' 16 or 128 (padding lanes)


@pytest.mark.parametrize("variant", ["16", "8", "16r"])
def test_prototype_radiance_is_the_megakernels_bit_for_bit(runtime, variant):
    scene = load_scene("mitsuba-cbox")
    tracer = PathTracer(runtime, scene, max_depth=8)
    pixels = rectangle_pixels(SIZE, 0, 0, SIZE, SIZE)
    sets = generate_sample_sets(runtime, make_sampler("independent", SPP), 5, pixels, None, None)
    reference = tracer.trace(sets, 5, SIZE, SIZE).to_host()
    proto = Prototype(runtime, tracer, variant, local_size=4, chunk=5, defines=[])
    event, radiance, counters, count = proto.trace(sets, 5, SIZE)
    event.wait()
    out, stats = proto.read(radiance, counters, count)
    assert reference.any()
    np.testing.assert_array_equal(out, reference)
    assert stats["rays"] == tracer.trace(sets, 5, SIZE, SIZE).rays
    assert 0 < stats["bounce_lanes"] <= proto.width * stats["bounce_steps"]


def test_the_probe_refuses_scenes_the_prototype_cannot_trace():
    with pytest.raises(ValueError, match="materials: diffuse only"):
        check_scene(load_scene("cornell-box-glossy"))
    check_scene(load_scene("mitsuba-cbox"))
