"""Host side of kernels/geometry_test.cl: a scene's rays intersected on the device."""

import numpy as np
import pyopencl as cl

from clrender.runtime import padded_global_size


def scene_arguments(runtime, scene, use_bvh: bool | None = None) -> tuple:
    """GEOMETRY_TEST_SCENE_PARAMS of a scene: through its BVH (use_bvh True), by brute force
    (False), or as the renderer chooses (None: scene.bvh()'s limit)."""
    upload = runtime.upload
    blocks = scene.quad_blocks()
    if use_bvh is None:
        nodes, prims = scene.bvh()
    elif use_bvh:
        nodes, prims = scene.bvh(brute_force_limit=-1)
    else:
        nodes, prims = scene.bvh(brute_force_limit=2**62)
    return (
        upload(scene.quads),
        upload(blocks),
        np.uint32(len(scene.quads)),
        np.uint32(len(blocks)),
        upload(scene.spheres),
        np.uint32(len(scene.spheres)),
        upload(scene.triangles),
        np.uint32(len(scene.triangles)),
        upload(nodes),
        np.uint32(len(nodes)),
        upload(prims),
    )


def _launch(runtime, name, count, arguments, outputs):
    kernel = runtime.kernel("geometry_test.cl", name)
    kernel(
        runtime.queue,
        (padded_global_size(count),),
        (runtime.local_size,),
        np.uint32(count),
        *arguments,
        *outputs,
    )


def _buffer(runtime, nbytes):
    return cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=max(nbytes, 4))


def _read(runtime, buffer, dtype, shape):
    out = np.empty(shape, dtype)
    cl.enqueue_copy(runtime.queue, out, buffer)
    return out


def device_intersect(runtime, scene, origins, directions, use_bvh=None):
    """(t, prim) of each ray's closest hit: t float32 (inf on a miss), prim int32 (-1)."""
    count = len(origins)
    t_buf, id_buf = _buffer(runtime, 4 * count), _buffer(runtime, 4 * count)
    rays = (
        runtime.upload(origins.astype(np.float32)),
        runtime.upload(directions.astype(np.float32)),
    )
    _launch(
        runtime,
        "intersect_rays",
        count,
        scene_arguments(runtime, scene, use_bvh) + rays,
        (t_buf, id_buf),
    )
    return _read(runtime, t_buf, np.float32, count), _read(runtime, id_buf, np.int32, count)


def device_occluded(runtime, scene, origins, directions, tmax, use_bvh=None):
    """Whether anything lies along each ray before tmax (bool array)."""
    count = len(origins)
    out = _buffer(runtime, 4 * count)
    rays = (
        runtime.upload(origins.astype(np.float32)),
        runtime.upload(directions.astype(np.float32)),
        runtime.upload(np.asarray(tmax, np.float32)),
    )
    _launch(
        runtime, "occluded_rays", count, scene_arguments(runtime, scene, use_bvh) + rays, (out,)
    )
    return _read(runtime, out, np.int32, count).astype(bool)


def device_surface(runtime, scene, origins, directions, use_bvh=None):
    """(p, ng, ns, error, material, emitter) of each ray's closest hit, error -1 where the ray
    misses (material and emitter undefined there)."""
    count = len(origins)
    frames, errors = _buffer(runtime, 36 * count), _buffer(runtime, 4 * count)
    indices = _buffer(runtime, 8 * count)
    extra = (
        runtime.upload(scene.triangle_normals),
        runtime.upload(origins.astype(np.float32)),
        runtime.upload(directions.astype(np.float32)),
    )
    _launch(
        runtime,
        "surface_rays",
        count,
        scene_arguments(runtime, scene, use_bvh) + extra,
        (frames, errors, indices),
    )
    frame = _read(runtime, frames, np.float32, (count, 3, 3))
    error = _read(runtime, errors, np.float32, count)
    material, emitter = _read(runtime, indices, np.int32, (count, 2)).T
    return frame[:, 0], frame[:, 1], frame[:, 2], error, material, emitter


def assert_bvh_equals_brute_force(runtime, scene, rng, rays=20000, extent=1.2):
    """Random rays from [-extent, extent]^3: the BVH's closest hits (ids and distances) and
    shadow-ray answers equal brute force's. Returns the brute-force ids (for coverage checks)."""
    origins = rng.uniform(-extent, extent, (rays, 3))
    directions = rng.normal(size=(rays, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    t_brute, prim_brute = device_intersect(runtime, scene, origins, directions, False)
    t_bvh, prim_bvh = device_intersect(runtime, scene, origins, directions, True)
    np.testing.assert_array_equal(prim_bvh, prim_brute)
    np.testing.assert_array_equal(t_bvh, t_brute)
    tmax = rng.uniform(0.0, 1.0, rays)
    blocked = device_occluded(runtime, scene, origins, directions, tmax, True)
    np.testing.assert_array_equal(blocked, t_brute < tmax)
    assert 0.1 < blocked.mean() < 0.9
    return prim_brute
