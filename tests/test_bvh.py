"""Triangles and the BVH on the device (kernels/geometry.h, clrender/bvh.py): triangle hits
against a float64 NumPy reference, the BVH against brute force on random scenes, watertight
edges, surface records, the BVH's structure, and a mesh rendering like the quad it replaces."""

import json
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from geometry_device import device_intersect, device_occluded, device_surface
from scene_texts import lit_room

from clrender.bvh import (
    BINARY_NODE_DTYPE,
    BVH_MAX_DEPTH,
    BVH_NODE_DTYPE,
    BVH_WIDTH,
    build_bvh,
    build_wide_bvh,
)
from clrender.sampling import generate_sample_sets, make_sampler, rectangle_pixels
from clrender.scene import load_scene
from clrender.scene_device import NORMALS_DTYPE, TRIANGLE_DTYPE
from clrender.trace import PathTracer
from clrender.wavefront import WavefrontPathTracer

HEADER = lit_room(16)


def toml_rows(array) -> str:
    return (
        "[" + ", ".join("[" + ", ".join(repr(float(x)) for x in row) + "]" for row in array) + "]"
    )


def mesh_text(positions, indices, normals=None, material="white") -> str:
    text = f'\n[[shapes]]\ntype = "mesh"\nmaterial = "{material}"\n'
    text += f"positions = {toml_rows(positions)}\n"
    text += "indices = [" + ", ".join(f"[{i}, {j}, {k}]" for i, j, k in indices) + "]\n"
    if normals is not None:
        text += f"normals = {toml_rows(normals)}\n"
    return text


def random_scene(tmp_path, seed, quads=20, spheres=10, triangles=60, normals=False):
    """Quads, spheres and a mesh of scattered small triangles in [-1, 1]^3 (plus the light)."""
    rng = np.random.default_rng(seed)
    text = HEADER
    for _ in range(quads):
        corner = rng.uniform(-1, 1, 3)
        edge1, edge2 = rng.normal(size=(2, 3)) * 0.3
        text += (
            f'\n[[shapes]]\ntype = "quad"\ncorner = {corner.tolist()}\n'
            f'edge1 = {edge1.tolist()}\nedge2 = {edge2.tolist()}\nmaterial = "white"\n'
        )
    for _ in range(spheres):
        center = rng.uniform(-1, 1, 3)
        text += (
            f'\n[[shapes]]\ntype = "sphere"\ncenter = {center.tolist()}\n'
            f'radius = {rng.uniform(0.05, 0.2)}\nmaterial = "white"\n'
        )
    centres = rng.uniform(-1, 1, (triangles, 1, 3))
    positions = (centres + rng.normal(size=(triangles, 3, 3)) * 0.25).reshape(-1, 3)
    indices = np.arange(3 * triangles).reshape(-1, 3)
    vertex_normals = rng.normal(size=positions.shape) if normals else None
    text += mesh_text(positions, indices, vertex_normals)
    path = tmp_path / f"random-{seed}.toml"
    path.write_text(text)
    return load_scene(path)


def random_rays(count, seed, spread=1.5):
    rng = np.random.default_rng(seed)
    origins = rng.uniform(-spread, spread, (count, 3))
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    return origins, directions


def reference_triangle_hits(scene, origins, directions):
    """Closest triangle hit in float64 (Moller-Trumbore): t (inf on a miss), triangle index,
    and how clear the answer is: the smallest distance, in barycentric coordinates, of the ray
    from any triangle's boundary (0 when another triangle lies within 1e-5 of the same
    distance)."""
    count = len(origins)
    p0, p1, p2 = (scene.triangles[k].astype(np.float64) for k in ("p0", "p1", "p2"))
    e1, e2 = p1 - p0, p2 - p0
    # rays x triangles
    pvec = np.cross(directions[:, None, :], e2[None, :, :])
    det = np.einsum("rtk,tk->rt", pvec, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        tvec = origins[:, None, :] - p0[None, :, :]
        u = np.einsum("rtk,rtk->rt", tvec, pvec) * inv
        qvec = np.cross(tvec, e1[None, :, :])
        v = np.einsum("rk,rtk->rt", directions, qvec) * inv
        t = np.einsum("tk,rtk->rt", e2, qvec) * inv
    hit = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    t = np.where(hit, t, np.inf)
    best = np.argmin(t, axis=1)
    best_t = t[np.arange(count), best]
    # How far every triangle ahead is from having the ray on its boundary
    with np.errstate(invalid="ignore"):
        edge = np.abs(np.minimum.reduce([u, v, 1 - u - v]))
        margin = np.where((det != 0) & (np.abs(t) > 0), edge, np.inf).min(axis=1)
    second = np.sort(t, axis=1)[:, 1]
    with np.errstate(invalid="ignore"):
        tie = np.isfinite(best_t) & (second - best_t <= 1e-5 * best_t)
    return best_t, np.where(np.isfinite(best_t), best, -1), np.where(tie, 0.0, margin)


@pytest.mark.parametrize("use_bvh", [False, True])
def test_triangle_hits_match_the_numpy_reference(runtime, tmp_path, use_bvh):
    scene = random_scene(tmp_path, 1, quads=0, spheres=0, triangles=200)
    origins, directions = random_rays(4000, 2)
    t, prim = device_intersect(runtime, scene, origins, directions, use_bvh)
    ref_t, ref_tri, margin = reference_triangle_hits(scene, origins, directions)
    first = len(scene.quads) + len(scene.spheres)
    ref_prim = np.where(ref_tri >= 0, ref_tri + first, -1)
    # The light quad (id 0) can be hit first: compare the other rays
    clear = (margin > 1e-4) & (prim != 0)
    assert clear.sum() > 3000 and (ref_prim[clear] >= 0).sum() > 300
    np.testing.assert_array_equal(prim[clear], ref_prim[clear])
    hit = clear & (ref_prim >= 0)
    np.testing.assert_allclose(t[hit], ref_t[hit], rtol=2e-5, atol=1e-6)
    assert np.all(np.isinf(t[clear & (ref_prim < 0)]))


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_bvh_closest_and_any_hit_equal_brute_force(runtime, tmp_path, seed):
    scene = random_scene(tmp_path, seed, quads=80, spheres=30, triangles=400)
    assert len(scene.quads) and len(scene.spheres) and len(scene.triangles)
    origins, directions = random_rays(20000, seed + 100)
    t_brute, prim_brute = device_intersect(runtime, scene, origins, directions, False)
    t_bvh, prim_bvh = device_intersect(runtime, scene, origins, directions, True)
    assert (prim_brute >= 0).mean() > 0.4
    np.testing.assert_array_equal(prim_bvh, prim_brute)
    np.testing.assert_array_equal(t_bvh, t_brute)
    # Any hit: shadow rays to random distances, about half of them blocked
    tmax = np.random.default_rng(seed).uniform(0.0, 2.0, len(origins))
    blocked_brute = device_occluded(runtime, scene, origins, directions, tmax, False)
    blocked_bvh = device_occluded(runtime, scene, origins, directions, tmax, True)
    np.testing.assert_array_equal(blocked_bvh, blocked_brute)
    np.testing.assert_array_equal(blocked_bvh, t_brute < tmax)
    assert 0.1 < blocked_bvh.mean() < 0.9


def test_triangle_grid_is_watertight(runtime, tmp_path):
    """Rays aimed exactly at the shared vertices and edges of a triangulated grid all hit it
    (the edge functions of neighbours are exact opposites)."""
    n = 8
    grid = np.stack(np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij"), -1)
    positions = np.concatenate([grid.reshape(-1, 2) / n - 0.5, np.zeros(((n + 1) ** 2, 1))], 1)
    corner = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).reshape(-1)
    indices = np.concatenate(
        [
            np.stack([corner, corner + n + 1, corner + n + 2], 1),
            np.stack([corner, corner + n + 2, corner + 1], 1),
        ]
    )
    path = tmp_path / "grid.toml"
    path.write_text(HEADER + mesh_text(positions, indices))
    scene = load_scene(path)
    # Targets: interior vertices and edge midpoints, from random origins above
    ticks = np.arange(1, 2 * n) / (2 * n) - 0.5
    targets = np.stack(np.meshgrid(ticks, ticks), -1).reshape(-1, 2)
    targets = np.concatenate([targets, np.zeros((len(targets), 1))], 1)
    rng = np.random.default_rng(9)
    origins = targets + rng.uniform(-1, 1, targets.shape) * [1, 1, 0] + [0, 0, 1.5]
    directions = targets - origins
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    for use_bvh in (False, True):
        t, prim = device_intersect(runtime, scene, origins, directions, use_bvh)
        assert np.all(prim >= 1), f"{np.sum(prim < 1)} rays leaked (bvh {use_bvh})"


def test_triangle_surface_record(runtime, tmp_path):
    scene = random_scene(tmp_path, 6, quads=0, spheres=0, triangles=100, normals=True)
    origins, directions = random_rays(3000, 7)
    t, prim = device_intersect(runtime, scene, origins, directions, True)
    p, ng, ns, error = device_surface(runtime, scene, origins, directions, True)
    hit = prim >= 1
    assert hit.sum() > 300
    tri = scene.triangles[prim[hit] - 1]
    p0, p1, p2 = (tri[k].astype(np.float64) for k in ("p0", "p1", "p2"))
    # Position: on the ray and on the triangle's plane, within the error bound
    on_ray = origins[hit] + t[hit, None].astype(np.float64) * directions[hit]
    assert np.all(np.abs(p[hit] - on_ray).max(axis=1) < 4 * error[hit] + 1e-6)
    normal = np.cross(p1 - p0, p2 - p0)
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    plane = np.abs(np.einsum("ij,ij->i", p[hit] - p0, normal))
    assert np.all(plane <= error[hit])
    assert np.all(error[hit] < 1e-4)
    # Geometric normal: counter-clockwise front side
    np.testing.assert_allclose(ng[hit], normal, atol=2e-6)
    # Shading normal: the interpolated vertex normals, turned to the geometric normal's side
    vn = scene.triangle_normals["n"][tri["normals"]].astype(np.float64)
    e1, e2, rel = p1 - p0, p2 - p0, p[hit] - p0
    d11, d12, d22 = (np.einsum("ij,ij->i", a, b) for a, b in ((e1, e1), (e1, e2), (e2, e2)))
    r1, r2 = np.einsum("ij,ij->i", rel, e1), np.einsum("ij,ij->i", rel, e2)
    den = d11 * d22 - d12 * d12
    b1, b2 = (d22 * r1 - d12 * r2) / den, (d11 * r2 - d12 * r1) / den
    bary = np.stack([1 - b1 - b2, b1, b2], 1)
    expected = np.einsum("ik,ikj->ij", bary, vn)
    expected /= np.linalg.norm(expected, axis=1)[:, None]
    expected *= np.sign(np.einsum("ij,ij->i", expected, normal))[:, None]
    np.testing.assert_allclose(ns[hit], expected, atol=1e-4)


def test_bvh_structure_covers_every_primitive_once():
    rng = np.random.default_rng(11)
    lower = rng.uniform(-1, 1, (5000, 3))
    upper = lower + rng.uniform(0, 0.05, (5000, 3))
    nodes, prims = build_bvh(lower, upper)
    assert nodes.dtype == BINARY_NODE_DTYPE
    np.testing.assert_array_equal(np.sort(prims), np.arange(5000))
    leaves = nodes[nodes["count"] > 0]
    covered = np.zeros(5000, int)
    for offset, count in zip(leaves["offset"], leaves["count"], strict=True):
        covered[offset : offset + count] += 1
    assert np.all(covered == 1)
    # Every leaf's box holds its primitives; every interior box holds its children's
    for node in leaves:
        members = prims[node["offset"] : node["offset"] + node["count"]]
        assert np.all(lower[members] >= node["lower"]) and np.all(upper[members] <= node["upper"])
    depth = np.zeros(len(nodes), int)
    for index, node in enumerate(nodes):
        if node["count"] < 0:
            for child in (node["offset"], node["offset"] + 1):
                assert child > index
                assert np.all(nodes[child]["lower"] >= node["lower"])
                assert np.all(nodes[child]["upper"] <= node["upper"])
                depth[child] = depth[index] + 1
    assert depth.max() <= BVH_MAX_DEPTH
    # Deterministic: the same bounds give the same tree
    again_nodes, again_prims = build_bvh(lower, upper)
    assert again_nodes.tobytes() == nodes.tobytes() and np.array_equal(again_prims, prims)


def test_wide_bvh_reaches_every_primitive_once_inside_its_boxes():
    rng = np.random.default_rng(12)
    lower = rng.uniform(-1, 1, (3000, 3))
    upper = lower + rng.uniform(0, 0.05, (3000, 3))
    nodes, prims = build_wide_bvh(lower, upper)
    assert nodes.dtype == BVH_NODE_DTYPE
    reached = np.zeros(3000, int)
    seen_nodes = np.zeros(len(nodes), int)
    seen_nodes[0] = 1
    for index, node in enumerate(nodes):
        for lane in range(BVH_WIDTH):
            count, child = node["count"][lane], node["child"][lane]
            box_low, box_high = node["lower"][:, lane], node["upper"][:, lane]
            if count == 0:
                assert child > index
                seen_nodes[child] += 1
                # The child's own children lie inside this box
                inner = nodes[child]
                used = inner["count"] >= 0
                assert np.all(inner["lower"][:, used] >= box_low[:, None])
                assert np.all(inner["upper"][:, used] <= box_high[:, None])
            elif count > 0:
                members = prims[child : child + count]
                reached[members] += 1
                assert np.all(lower[members] >= box_low) and np.all(upper[members] <= box_high)
    assert np.all(reached == 1) and np.all(seen_nodes == 1)
    # Nodes are well filled (a binary tree would use 2 lanes)
    assert (nodes["count"] >= 0).sum(axis=1).mean() > 5.0


def test_bvh_depth_is_capped_for_a_pathological_scene():
    # Boxes at exponentially growing positions: SAH splits off one primitive per level
    x = 2.0 ** np.arange(100)
    lower = np.stack([x, np.zeros(100), np.zeros(100)], 1)
    nodes, prims = build_bvh(lower, lower + 0.5)
    np.testing.assert_array_equal(np.sort(prims), np.arange(100))
    depth = np.zeros(len(nodes), int)
    for index, node in enumerate(nodes):
        if node["count"] < 0:
            depth[node["offset"] : node["offset"] + 2] = depth[index] + 1
    assert depth.max() <= BVH_MAX_DEPTH


def test_struct_layouts_match_the_kernel(runtime):
    sizes = np.zeros(3, np.uint32)
    buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=sizes.nbytes)
    runtime.kernel("geometry_test.cl", "struct_sizes")(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, sizes, buf)
    assert list(sizes) == [TRIANGLE_DTYPE.itemsize, NORMALS_DTYPE.itemsize, BVH_NODE_DTYPE.itemsize]


def quads_as_meshes(text: str) -> str:
    """A scene text whose non-emitting 4-vertex quads become meshes of 2 triangles."""
    out = []
    for block in text.split("[[shapes]]"):
        if 'type = "quad"' in block and "emission" not in block and "vertices" in block:
            block = block.replace('type = "quad"', 'type = "mesh"')
            block = block.replace("vertices = [", "indices = [[0, 1, 2], [0, 2, 3]]\npositions = [")
        out.append(block)
    return "[[shapes]]".join(out)


def render_mean(runtime, scene, size=16, spp=64):
    tracer = PathTracer(runtime, scene, max_depth=4)
    pixels = rectangle_pixels(size, 0, 0, size, size)
    sets = generate_sample_sets(runtime, make_sampler("independent", spp), 5, pixels)
    radiance = tracer.trace(sets, 5, size, size).to_host()
    return radiance.reshape(size, size, spp, 3).mean(axis=2)


def test_two_triangle_meshes_render_like_their_quads(runtime, tmp_path):
    """mitsuba-cbox with every wall a mesh of 2 triangles: the same random numbers give the
    same paths but for float rounding, so the images agree far inside their noise."""
    base = load_scene("mitsuba-cbox")
    path = tmp_path / "mesh-cbox.toml"
    path.write_text(quads_as_meshes(base.path.read_text()))
    meshed = load_scene(path)
    assert len(meshed.triangles) >= 10 and len(meshed.quads) < len(base.quads)
    quad_image = render_mean(runtime, base)
    mesh_image = render_mean(runtime, meshed)
    assert quad_image.mean() > 0.05
    # Noise of the image mean (64 paths per pixel, 256 pixels) is about 2 %: demand 0.5 %
    assert mesh_image.mean() == pytest.approx(quad_image.mean(), rel=0.005)
    assert np.abs(mesh_image - quad_image).mean() < 0.02 * quad_image.mean()


def test_bvh_scaling_bench_runs_and_reports_every_figure(runtime, tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "bench"))
    import bvh_scaling

    output = tmp_path / "bvh.json"
    bvh_scaling.main(
        ["--triangles", "20", "2000", "--quads", "66", "--compare-triangles", "20"]
        + ["--size", "8", "--spp", "2"]
        + ["--repeats", "1", "--output", str(output)]
    )
    data = json.loads(output.read_text())
    counts = [row["triangles"] for row in data["triangles"]]
    assert counts[0] == 20 and abs(counts[1] - 2000) < 50
    assert all(row["rays_per_s"] > 0 and row["build_wall_s"] > 0 for row in data["triangles"])
    assert [row["scene"] for row in data["cornell"]][0] == "cornell-box"
    row = data["quads"][0]
    assert row["primitives"] == 66 and not row["default_uses_bvh"]
    assert data["meshes"][0]["default_uses_bvh"]  # 20 triangles
    assert row["brute_rays_per_s"] > 0 and row["bvh_rays_per_s"] > 0


def test_wavefront_equals_the_megakernel_on_a_mesh_scene(runtime, tmp_path):
    """The wavefront stages call geometry.h too: bit-identical radiance on meshes through the
    BVH, shading normals included."""
    base = load_scene("mitsuba-cbox")
    text = quads_as_meshes(base.path.read_text())
    rng = np.random.default_rng(13)
    positions = rng.uniform(-0.5, 0.5, (30, 3))
    text += mesh_text(positions, np.arange(30).reshape(-1, 3), rng.normal(size=(30, 3)))
    path = tmp_path / "mesh-cbox.toml"
    path.write_text(text)
    scene = load_scene(path)
    mega = PathTracer(runtime, scene)
    assert len(mega.bvh_nodes) > 0 and np.any(scene.triangles["normals"] >= 0)
    wave = WavefrontPathTracer(runtime, scene, wave_paths=1500)
    pixels = rectangle_pixels(16, 0, 0, 16, 16)
    sets = generate_sample_sets(runtime, make_sampler("independent", 16), 3, pixels)
    a, b = mega.trace(sets, 3, 16, 16), wave.trace(sets, 3, 16, 16)
    radiance = a.to_host()
    np.testing.assert_array_equal(b.to_host(), radiance)
    assert a.rays == b.rays and np.count_nonzero(radiance.sum(axis=1)) > len(radiance) // 2
