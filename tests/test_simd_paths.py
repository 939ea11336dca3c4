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

from simd_paths_probe import (  # noqa: E402
    Prototype,
    check_scene,
    deals_holding_work,
    parse_variant,
    pocl_deals,
)

SIZE = 24
SPP = 3  # 24 * 24 * 3 samples: not a multiple of the work-items' 16 or 128 (padding lanes)
CHUNK = 5  # regeneration: 16 * 5 samples a chunk, 22 chunks (the last one short)


def trace_both(runtime, variant):
    """(megakernel radiance, its ray count, the prototype, its radiance, its counters)."""
    scene = load_scene("mitsuba-cbox")
    tracer = PathTracer(runtime, scene, max_depth=8)
    pixels = rectangle_pixels(SIZE, 0, 0, SIZE, SIZE)
    sets = generate_sample_sets(runtime, make_sampler("independent", SPP), 5, pixels, None, None)
    mega = tracer.trace(sets, 5, SIZE, SIZE)
    proto = Prototype(runtime, tracer, variant, local_size=4, chunk=CHUNK, defines=[])
    event, radiance, counters, count = proto.trace(sets, 5, SIZE)
    event.wait()
    out, stats = proto.read(radiance, counters, count)
    return mega.to_host(), mega.rays, proto, out, stats


@pytest.mark.parametrize(
    "variant", ["16", "8", "16r/front", "16r/spread", "16r/queue", "8r/queue", "16r/c1/l16"]
)
def test_prototype_radiance_is_the_megakernels_bit_for_bit(runtime, variant):
    reference, rays, proto, out, stats = trace_both(runtime, variant)
    assert reference.any()
    np.testing.assert_array_equal(out, reference)
    assert stats["rays"] == rays
    assert 0 < stats["bounce_lanes"] <= proto.width * stats["bounce_steps"]


def test_regeneration_deals_its_chunks_over_the_whole_launch(runtime):
    """PoCL deals a launch's work-groups to its threads in runs of 256 per thread from the
    front: the chunks packed into the first groups (front) all go to one thread; spread, the
    last chunk runs in the launch's last groups; queued, the work-items take every chunk."""
    count = SIZE * SIZE * SPP
    chunks = -(-count // (16 * CHUNK))
    for layout in ("front", "spread", "queue"):
        *_, proto, _, stats = trace_both(runtime, f"16r/{layout}")
        launched = proto.global_size(count)
        assert launched >= 1 << 16 and launched % proto.local_size == 0
        if layout == "front":
            assert stats["last_group"] == -(-chunks // proto.local_size)
        elif layout == "spread":
            last_item = (chunks - 1) * launched // chunks
            assert stats["last_group"] == last_item // proto.local_size + 1
            assert stats["last_group"] > 0.95 * launched // proto.local_size
        else:
            # every chunk taken once, and every work-item asked once more and found none
            assert stats["next_chunk"] == chunks + launched


@pytest.mark.parametrize("layout", ["front", "spread", "queue"])
def test_regeneration_over_no_samples_traces_nothing(runtime, layout):
    scene = load_scene("mitsuba-cbox")
    tracer = PathTracer(runtime, scene, max_depth=8)
    sets = generate_sample_sets(
        runtime, make_sampler("independent", 1), 5, rectangle_pixels(4, 0, 0, 4, 4), None, None
    )
    proto = Prototype(runtime, tracer, f"16r/{layout}", local_size=4, chunk=CHUNK, defines=[])
    event, radiance, counters, _ = proto.trace(sets, 5, 4, count=0)
    event.wait()
    _, stats = proto.read(radiance, counters, 0)
    assert stats["rays"] == stats["last_group"] == 0
    assert stats["next_chunk"] == 0  # not even a look at the queue


def test_variant_options_are_checked():
    assert parse_variant("8r/c4/l64/spread", 16, 32, "queue") == {
        "width": 8,
        "regenerate": True,
        "local_size": 64,
        "chunk": 4,
        "layout": "spread",
    }
    with pytest.raises(ValueError, match="option 'spread' is not"):
        parse_variant("16/spread", 16, 32, "queue")
    with pytest.raises(ValueError, match="lanes must be 8 or 16"):
        parse_variant("4r", 16, 32, "queue")


def test_the_probe_refuses_scenes_the_prototype_cannot_trace():
    with pytest.raises(ValueError, match="materials: diffuse only"):
        check_scene(load_scene("cornell-box-glossy"))
    check_scene(load_scene("mitsuba-cbox"))


def test_the_model_of_pocls_deals_of_work_groups():
    """pthread_scheduler.c (PoCL 3.0, 3.1) on 2 threads: runs of 512 groups while more than
    1 024 remain, then 64, then halving; 8 192 regenerating work-items of 16 (512 groups) at the
    front of a 65 536-item launch sit in one run: one thread."""
    runs = pocl_deals(4096, 2)
    assert runs[:7] == [512] * 6 + [64] and sum(runs) == 4096 and runs[-2:] == [1, 1]
    assert pocl_deals(100, 4)[:3] == [25, 19, 14]  # an even share of what remains
    assert deals_holding_work(4096, list(range(512))) == 1
    assert deals_holding_work(4096, list(range(1024))) == 2
    assert deals_holding_work(4096, [0, 4095]) == 2
