// Test kernel (built only by tests/test_mesh_emitters.py): lights.h's emitter pick, uniform
// triangle sampling and NEE of emitting triangles and quads, from given reference points and
// random numbers, against NumPy twins of the same formulas.
#include "scene_types.h"
#include "lights.h"

// For each reference point p[i] and random triple u[i] (emitter choice, point): the picked
// emitter, the sampled direction wi (3 floats), the distance to the emitter point, the
// sample's pdfW from Light_SampleLi and the pdfW Light_HitPdfW gives for the same point (the
// cosine recomputed from the picked shape's geometric normal), and the barycentric coordinates
// Triangle_SampleUniform draws from (u.y, u.z).
__kernel void sample_mesh_light(uint count, __global const Quad *quads, uint quad_count,
                                __global const Triangle *triangles, uint triangle_count,
                                __global const Emitter *emitters, uint emitter_count,
                                __global const float *points, __global const float *u,
                                __global uint *picked_out, __global float *wi_out,
                                __global float *dist_out, __global float *pdf_out,
                                __global float *hit_pdf_out, __global float *bary_out)
{
    uint i = get_global_id(0);
    if (i >= count)
        return;
    SceneData scene = {.quads = quads, .triangles = triangles, .emitters = emitters,
                       .quad_count = quad_count, .triangle_count = triangle_count,
                       .emitter_count = emitter_count};
    float3 p = vload3(i, points);
    float3 ui = vload3(i, u);
    float3 wi = (float3)(0.0f);
    float dist = 0.0f, pdfW;
    uint picked;
    Light_SampleLi(&scene, p, ui, &wi, &dist, &pdfW, &picked);
    __global const Emitter *emitter = &emitters[picked];
    float3 normal;
    if (emitter->shape == EMITTER_TRIANGLE) {
        __global const Triangle *tri = &triangles[emitter->index];
        normal = Normalize3(Cross3(Load3(tri->p1) - Load3(tri->p0),
                                   Load3(tri->p2) - Load3(tri->p0)));
    } else {
        normal = Load3(quads[emitter->index].normal);
    }
    picked_out[i] = picked;
    vstore3(wi, i, wi_out);
    dist_out[i] = dist;
    pdf_out[i] = pdfW;
    hit_pdf_out[i] = Light_HitPdfW(&scene, emitter, p, dist, -Dot3(normal, wi));
    vstore3(Triangle_SampleUniform((float2)(ui.y, ui.z)), i, bary_out);
}
