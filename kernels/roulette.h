// Russian roulette, shared by the megakernel (integrator.cl) and the wavefront (wavefront.cl).
//
// pbrt-v4's rule: after the BSDF sample of vertex depth >= RUSSIAN_ROULETTE_MIN_DEPTH (1: from
// the second vertex on; 4 is the vertex where Mitsuba's rr_depth 5 starts) the path ends with
// probability q = max(0, 1 - max(beta * eta_scale)), where eta_scale undoes the 1 / eta'^2
// radiance scaling of the refractions so far (a path inside glass is not culled for it).
// bench/roulette_study.py builds the kernels with other values (RUSSIAN_ROULETTE_ETA_SCALE 0:
// beta alone) to measure them.
#ifndef CLRENDER_ROULETTE_H
#define CLRENDER_ROULETTE_H

#ifndef RUSSIAN_ROULETTE_MIN_DEPTH
#define RUSSIAN_ROULETTE_MIN_DEPTH 1
#endif
#ifndef RUSSIAN_ROULETTE_ETA_SCALE
#define RUSSIAN_ROULETTE_ETA_SCALE 1
#endif

// eta_scale times the radiance scaling of a refraction (wi on the other side of the surface)
CL_INLINE float Roulette_EtaScale(float eta_scale, __global const Material *material,
                                  float3 wo_local, float3 wi_local)
{
    if (material->type == MATERIAL_DIELECTRIC && wi_local.z * wo_local.z < 0.0f) {
        float eta_rel = wo_local.z > 0.0f ? material->eta[0] : 1.0f / material->eta[0];
        eta_scale *= eta_rel * eta_rel;
    }
    return eta_scale;
}

// The probability of ending the path after this vertex (0: it goes on at full weight)
CL_INLINE float Roulette_EndProbability(int russian_roulette, int depth, float3 beta,
                                        float eta_scale)
{
    float rr_beta_max = Fmax(beta.x, Fmax(beta.y, beta.z));
    if (RUSSIAN_ROULETTE_ETA_SCALE)
        rr_beta_max *= eta_scale;
    if (!(russian_roulette && depth >= RUSSIAN_ROULETTE_MIN_DEPTH && rr_beta_max < 1.0f))
        return 0.0f;
    return Fmax(0.0f, 1.0f - rr_beta_max);
}

#endif
