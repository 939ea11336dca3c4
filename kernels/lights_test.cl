// Test kernel (built only by tests/test_sphere_lights.py): lights.h's sampling of an emitting
// sphere's cone and its pdf, from given reference points and random numbers, against a
// float64 NumPy twin of the same formulas and a chi-square test of the directions.
#include "scene_types.h"
#include "lights.h"

// For each reference point p[i] and random pair u[i]: the sampled direction wi (3 floats),
// the distance along it to the sphere, the sample's pdfW from Light_SampleLi (emitter pick
// included) and the pdfW Light_HitPdfW gives the same direction (it must agree).
__kernel void sample_sphere_light(uint count, __global const Sphere *spheres,
                                  __global const Emitter *emitters, uint emitter_count,
                                  __global const float *points, __global const float2 *u,
                                  __global float *wi_out, __global float *dist_out,
                                  __global float *pdf_out, __global float *hit_pdf_out)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    SceneData scene = {.spheres = spheres, .emitters = emitters, .sphere_count = 1u,
                       .emitter_count = emitter_count};
    float3 p = vload3(i, points);
    float3 wi = (float3)(0.0f);
    float dist = 0.0f, pdfW;
    uint picked;
    Light_SampleLi(&scene, p, (float3)(0.0f, u[i]), &wi, &dist, &pdfW, &picked);
    vstore3(wi, i, wi_out);
    dist_out[i] = dist;
    pdf_out[i] = pdfW;
    hit_pdf_out[i] = Light_HitPdfW(&scene, &emitters[0], p, dist, 1.0f);
}
