// Test kernels (built only by tests/test_bsdf.py): bsdf.h's BSDF_Sample, BSDF_Eval and
// BSDF_PdfW on arrays of directions, for the chi-square and consistency tests.
#include "scene_types.h"
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
