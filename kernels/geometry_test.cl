// Test kernels (built only by tests/test_geometry.py and tests/test_bvh.py): geometry.h's
// Scene_Intersect and Scene_Occluded on arrays of rays, against float64 NumPy references and
// against each other (BVH and brute force: bvh_node_count 0 selects brute force).
#include "scene_types.h"
#include "geometry.h"

#define GEOMETRY_TEST_SCENE_PARAMS                                                             \
    __global const Quad *quads, __global const QuadBlock *quad_blocks, uint quad_count,        \
        uint quad_block_count, __global const Sphere *spheres, uint sphere_count,              \
        __global const Triangle *triangles, uint triangle_count, __global const BVHNode *bvh_nodes, \
        uint bvh_node_count, __global const uint *bvh_prims
#define GEOMETRY_TEST_SCENE                                                                    \
    {.quads = quads, .quad_blocks = quad_blocks, .spheres = spheres, .triangles = triangles,  \
     .bvh_nodes = bvh_nodes, .bvh_prims = bvh_prims, .quad_count = quad_count,                \
     .quad_block_count = quad_block_count, .sphere_count = sphere_count,                      \
     .triangle_count = triangle_count, .bvh_node_count = bvh_node_count}

// Closest hit of each ray (unit directions): distance (INFINITY on a miss) and primitive id
// (Scene_HitPrimitive of the hit id).
__kernel void intersect_rays(uint count, GEOMETRY_TEST_SCENE_PARAMS,
                             __global const float *origins, __global const float *directions,
                             __global float *t, __global int *prim)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    SceneData scene = GEOMETRY_TEST_SCENE;
    int id;
    t[i] = Scene_Intersect(&scene, vload3(i, origins), vload3(i, directions), INFINITY, &id);
    prim[i] = Scene_HitPrimitive(&scene, id);
}

// Whether anything lies along each ray before tmax[i] (1) or not (0).
__kernel void occluded_rays(uint count, GEOMETRY_TEST_SCENE_PARAMS,
                            __global const float *origins, __global const float *directions,
                            __global const float *tmax, __global int *occluded)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    SceneData scene = GEOMETRY_TEST_SCENE;
    occluded[i] =
        Scene_Occluded(&scene, vload3(i, origins), vload3(i, directions), tmax[i]) ? 1 : 0;
}

// The surface record of each ray's closest hit: position, geometric and shading normal (9
// floats per ray), the error bound (-1 where the ray misses), material and emitter (2 ints).
__kernel void surface_rays(uint count, GEOMETRY_TEST_SCENE_PARAMS,
                           __global const TriangleNormals *triangle_normals,
                           __global const float *origins, __global const float *directions,
                           __global float *frames, __global float *errors, __global int *indices)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    SceneData scene = GEOMETRY_TEST_SCENE;
    scene.triangle_normals = triangle_normals;
    float3 o = vload3(i, origins);
    float3 d = vload3(i, directions);
    int id;
    float t = Scene_Intersect(&scene, o, d, INFINITY, &id);
    if (id < 0) {
        errors[i] = -1.0f;
        return;
    }
    Surface s = Scene_Surface(&scene, o, d, t, id);
    vstore3(s.p, 3 * i, frames);
    vstore3(s.ng, 3 * i + 1, frames);
    vstore3(s.ns, 3 * i + 2, frames);
    errors[i] = s.error;
    indices[2 * i] = s.material;
    indices[2 * i + 1] = s.emitter;
}

// sizeof of the mesh and BVH structs shared with the host, to check the NumPy dtypes.
__kernel void struct_sizes(__global uint *sizes)
{
    sizes[0] = sizeof(Triangle);
    sizes[1] = sizeof(TriangleNormals);
    sizes[2] = sizeof(BVHNode);
}
