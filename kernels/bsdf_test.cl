// Test entry points exposing the BSDFs, the intersection routines and the struct layouts to
// the host test suite (tests/test_bsdf.py, tests/test_geometry.py, tests/test_scene.py).
#include "scene_types.h"
#include "geometry.h"
#include "bsdf.h"

// Sample one direction per (wo, u) pair: wi, weight f |cos| / pdfW and pdfW.
__kernel void bsdf_sample(uint count, __global const Material *material,
                          __global const float *wo, __global const float *u,
                          __global float *wi, __global float *weight, __global float *pdfW)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    float3 wi_i;
    float pdf_i;
    float3 w = BSDF_Sample(material, vload3(i, wo), vload3(i, u), &wi_i, &pdf_i);
    vstore3(wi_i, i, wi);
    vstore3(w, i, weight);
    pdfW[i] = pdf_i;
}

// f (no cosine) and pdfW for each (wo, wi) pair.
__kernel void bsdf_eval(uint count, __global const Material *material,
                        __global const float *wo, __global const float *wi, __global float *f,
                        __global float *pdfW)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    float3 a = vload3(i, wo);
    float3 b = vload3(i, wi);
    vstore3(BSDF_Eval(material, a, b), i, f);
    pdfW[i] = BSDF_PdfW(material, a, b);
}

// Closest hit of each ray (unit directions): distance (INFINITY on a miss) and primitive id.
__kernel void intersect_rays(uint count, __global const QuadBlock *quad_blocks,
                             uint quad_count, uint quad_block_count,
                             __global const Sphere *spheres, uint sphere_count,
                             __global const float *origins, __global const float *directions,
                             __global float *t, __global int *prim)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    SceneData scene = {0, quad_blocks, spheres, 0, 0, quad_count, quad_block_count, sphere_count,
                       0u, 0.0f};
    int id;
    t[i] = Scene_Intersect(&scene, vload3(i, origins), vload3(i, directions), INFINITY, &id);
    prim[i] = id;
}

// sizeof of the structs shared with the host, to check the NumPy dtypes.
__kernel void struct_sizes(__global uint *sizes)
{
    sizes[0] = sizeof(Quad);
    sizes[1] = sizeof(Sphere);
    sizes[2] = sizeof(Material);
    sizes[3] = sizeof(Emitter);
    sizes[4] = sizeof(Camera);
    sizes[5] = sizeof(QuadBlock);
}
