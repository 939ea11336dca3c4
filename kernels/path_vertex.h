// What the megakernel (integrator.cl) and the wavefront (wavefront.cl) do alike at a path
// vertex: the power heuristic of multiple importance sampling and the shading normal.
#ifndef CLRENDER_PATH_VERTEX_H
#define CLRENDER_PATH_VERTEX_H

#include "bsdf.h"
#include "vecmath.h"

// Power heuristic (beta = 2) weight of a sample drawn with pdf_a against a strategy of pdf_b
CL_INLINE float PathVertex_PowerHeuristic(float pdf_a, float pdf_b)
{
    float a2 = pdf_a * pdf_a;
    return a2 / (a2 + pdf_b * pdf_b);
}

// The shading normal in *n, from the surface's shading normal ns (on the side of its geometric
// normal ng; ns = ng except on meshes with vertex normals): two-sided surfaces face wo, one-sided
// ones are black from behind (false: the path ends there); the geometric normal tells the side.
// Specular surfaces keep the front side's normal.
CL_INLINE bool PathVertex_ShadingNormal(__global const Material *material, float3 ng, float3 ns,
                                        float3 wo, float3 *n)
{
    *n = ns;
    if (!BSDF_IsSpecular(material) && Dot3(ng, wo) < 0.0f) {
        if (!material->two_sided)
            return false;
        *n = -ns;
    }
    return true;
}

#endif
