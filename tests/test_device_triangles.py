"""With a BVH the Triangle records stay off the device unless a triangle emits: the BVH's
leaf blocks hold every triangle's vertices and surface indices."""

import dataclasses

import numpy as np

from clrender import trace
from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import load_scene
from clrender.scene_device import TRIANGLE_DTYPE, pack_triangles
from clrender.trace import PathTracer, device_triangles

FORCE_BVH = -1  # brute_force_limit that builds a BVH for every scene
SIZE = 24


def octahedron_in_the_box(material: int = 0):
    """mitsuba-cbox with a white octahedron (8 triangles, counter-clockwise from outside)."""
    positions = 0.4 * np.array(
        [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64
    )
    indices = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    )
    mesh = {"positions": positions, "indices": indices, "normals": None, "material": material}
    packed, normals = pack_triangles([mesh])
    base = load_scene("mitsuba-cbox")
    return dataclasses.replace(base, triangles=packed, triangle_normals=normals)


def test_the_records_go_to_the_device_only_without_a_bvh_or_with_an_emitting_triangle():
    triangles = octahedron_in_the_box().triangles
    assert len(device_triangles(triangles, has_bvh=False)) == len(triangles)
    assert len(device_triangles(triangles, has_bvh=True)) == 0
    emitting = triangles.copy()
    emitting["emitter"][3] = 0
    assert len(device_triangles(emitting, has_bvh=True)) == len(triangles)


def traced(runtime, tracer):
    pixels = rectangle_pixels(SIZE, 0, 0, SIZE, SIZE)
    sets = generate_sample_sets(runtime, make_sampler("independent", 4), 5, pixels)
    result = tracer.trace(sets, 5, SIZE, SIZE)
    result.wait()
    return result.to_host()


def test_a_bvh_render_without_the_records_is_the_render_with_them(runtime, monkeypatch):
    scene = octahedron_in_the_box()
    lean = PathTracer(runtime, scene, max_depth=4, brute_force_limit=FORCE_BVH)
    assert len(lean.bvh_nodes) > 0
    assert lean._buffers["triangles"].size < TRIANGLE_DTYPE.itemsize * len(scene.triangles)
    monkeypatch.setattr(trace, "device_triangles", lambda triangles, has_bvh: triangles)
    full = PathTracer(runtime, scene, max_depth=4, brute_force_limit=FORCE_BVH)
    assert full._buffers["triangles"].size >= TRIANGLE_DTYPE.itemsize * len(scene.triangles)
    lean_image, full_image = traced(runtime, lean), traced(runtime, full)
    assert np.any(lean_image > 0)
    np.testing.assert_array_equal(lean_image, full_image)
