// BSDFs in a local shading frame: z is the normal, directions point away from the surface.
// Per material: BSDF_Eval (f, no cosine), BSDF_PdfW (solid-angle pdf of BSDF_Sample) and
// BSDF_Sample (a direction wi, its pdfW and the weight f |cos wi| / pdfW).
// Diffuse and rough conductors reflect only between directions with z > 0 (the integrator
// flips the frame of two-sided surfaces to face wo); the smooth dielectric's frame is the
// geometric normal (outside is z > 0) and it is a delta BSDF: Eval and PdfW are 0.
#ifndef CLRENDER_BSDF_H
#define CLRENDER_BSDF_H

#include "scene_types.h"
#include "vecmath.h"

typedef struct {
    float3 s;
    float3 t;
    float3 n;
} Frame;

// An orthonormal frame around the unit normal n (Duff et al. 2017, branchless).
CL_INLINE Frame Frame_FromNormal(float3 n)
{
    float sign = Copysign(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    Frame frame;
    frame.s = (float3)(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    frame.t = (float3)(b, sign + n.y * n.y * a, -n.y);
    frame.n = n;
    return frame;
}

CL_INLINE float3 Frame_ToLocal(Frame frame, float3 v)
{
    return (float3)(Dot3(v, frame.s), Dot3(v, frame.t), Dot3(v, frame.n));
}

CL_INLINE float3 Frame_ToWorld(Frame frame, float3 v)
{
    return v.x * frame.s + v.y * frame.t + v.z * frame.n;
}

// ----------------------------------------------------------------------------- Fresnel

// Unpolarised Fresnel reflectance of a smooth dielectric interface; eta = eta_inside /
// eta_outside, cos_i > 0 on the outside. Total internal reflection gives 1.
CL_INLINE float Fresnel_Dielectric(float cos_i, float eta)
{
    cos_i = Fmin(Fmax(cos_i, -1.0f), 1.0f);
    if (cos_i < 0.0f) {
        eta = 1.0f / eta;
        cos_i = -cos_i;
    }
    float sin2_t = (1.0f - cos_i * cos_i) / (eta * eta);
    if (sin2_t >= 1.0f)
        return 1.0f;
    float cos_t = Sqrt(1.0f - sin2_t);
    float r_parallel = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    float r_perpendicular = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    return 0.5f * (r_parallel * r_parallel + r_perpendicular * r_perpendicular);
}

// Unpolarised Fresnel reflectance of a conductor of complex index eta + i k (outside: 1),
// per RGB channel, for 0 <= cos_i <= 1 (pbrt-v3 FrConductor).
CL_INLINE float3 Fresnel_Conductor(float cos_i, float3 eta, float3 k)
{
    float cos2 = cos_i * cos_i;
    float sin2 = 1.0f - cos2;
    float3 eta2 = eta * eta;
    float3 k2 = k * k;
    float3 t0 = eta2 - k2 - sin2;
    float3 a2_plus_b2 = Sqrt3(t0 * t0 + 4.0f * eta2 * k2);
    float3 t1 = a2_plus_b2 + cos2;
    float3 a = Sqrt3(Fmax3(0.5f * (a2_plus_b2 + t0), 0.0f));
    float3 t2 = 2.0f * cos_i * a;
    float3 rs = (t1 - t2) / (t1 + t2);
    float3 t3 = cos2 * a2_plus_b2 + sin2 * sin2;
    float3 t4 = t2 * sin2;
    float3 rp = rs * (t3 - t4) / (t3 + t4);
    return 0.5f * (rp + rs);
}

// ----------------------------------------------------------------------------- diffuse

CL_INLINE float3 Diffuse_Eval(__global const Material *m, float3 wo, float3 wi)
{
    bool same_side = wo.z > 0.0f && wi.z > 0.0f;
    return same_side ? Load3(m->albedo) * M_1_PI_F : (float3)(0.0f);
}

CL_INLINE float Diffuse_PdfW(float3 wo, float3 wi)
{
    return (wo.z > 0.0f && wi.z > 0.0f) ? wi.z * M_1_PI_F : 0.0f;
}

// Cosine-weighted hemisphere: pdfW = cos(wi) / pi, weight = albedo.
CL_INLINE float3 Diffuse_Sample(__global const Material *m, float3 wo, float2 u, float3 *wi,
                                float *pdfW)
{
    float r = Sqrt(u.x);
    float cos_phi;
    float sin_phi = SinCos2Pi(u.y, &cos_phi);
    *wi = (float3)(r * cos_phi, r * sin_phi, Sqrt(Fmax(0.0f, 1.0f - u.x)));
    *pdfW = Diffuse_PdfW(wo, *wi);
    return *pdfW > 0.0f ? Load3(m->albedo) : (float3)(0.0f);
}

// ----------------------------------------------------------------------------- GGX

// GGX normal distribution D(m) for a microfacet normal m with m.z > 0.
CL_INLINE float GGX_D(float3 m, float alpha)
{
    float a2 = alpha * alpha;
    float d = m.z * m.z * (a2 - 1.0f) + 1.0f;
    return a2 / (M_PI_F * d * d);
}

// Smith's Lambda for GGX: G1(w) = 1 / (1 + Lambda(w)).
CL_INLINE float GGX_Lambda(float3 w, float alpha)
{
    float tan2 = (w.x * w.x + w.y * w.y) / (w.z * w.z);
    return 0.5f * (Sqrt(1.0f + alpha * alpha * tan2) - 1.0f);
}

// A microfacet normal from the distribution of normals visible from wo (Heitz 2018).
CL_INLINE float3 GGX_SampleVisibleNormal(float3 wo, float alpha, float2 u)
{
    float3 vh = Normalize3((float3)(alpha * wo.x, alpha * wo.y, wo.z));
    float lensq = vh.x * vh.x + vh.y * vh.y;
    float3 t1 =
        lensq > 0.0f ? (float3)(-vh.y, vh.x, 0.0f) * (1.0f / Sqrt(lensq)) : (float3)(1, 0, 0);
    float3 t2 = Cross3(vh, t1);
    float r = Sqrt(u.x);
    float cos_phi;
    float sin_phi = SinCos2Pi(u.y, &cos_phi);
    float p1 = r * cos_phi;
    float p2 = r * sin_phi;
    float s = 0.5f * (1.0f + vh.z);
    p2 = (1.0f - s) * Sqrt(Fmax(0.0f, 1.0f - p1 * p1)) + s * p2;
    float3 nh = p1 * t1 + p2 * t2 + Sqrt(Fmax(0.0f, 1.0f - p1 * p1 - p2 * p2)) * vh;
    return Normalize3((float3)(alpha * nh.x, alpha * nh.y, Fmax(1e-7f, nh.z)));
}

// ----------------------------------------------------------------------------- rough conductor

// f = D(wh) G2(wo, wi) F(wo.wh) / (4 cos_o cos_i), height-correlated Smith G2.
CL_INLINE float3 Conductor_Eval(__global const Material *m, float3 wo, float3 wi)
{
    if (!(wo.z > 0.0f && wi.z > 0.0f))
        return (float3)(0.0f);
    float alpha = m->alpha;
    float3 wh = Normalize3(wo + wi);
    float g2 = 1.0f / (1.0f + GGX_Lambda(wo, alpha) + GGX_Lambda(wi, alpha));
    float3 fresnel = Fresnel_Conductor(Dot3(wo, wh), Load3(m->eta), Load3(m->k));
    return fresnel * (GGX_D(wh, alpha) * g2 / (4.0f * wo.z * wi.z));
}

// Visible-normal sampling: pdfW = D(wh) G1(wo) / (4 cos_o).
CL_INLINE float Conductor_PdfW(__global const Material *m, float3 wo, float3 wi)
{
    if (!(wo.z > 0.0f && wi.z > 0.0f))
        return 0.0f;
    float alpha = m->alpha;
    float3 wh = Normalize3(wo + wi);
    return GGX_D(wh, alpha) / ((1.0f + GGX_Lambda(wo, alpha)) * 4.0f * wo.z);
}

// Weight f cos_i / pdfW = F(wo.wh) G2 / G1(wo).
CL_INLINE float3 Conductor_Sample(__global const Material *m, float3 wo, float2 u, float3 *wi,
                                  float *pdfW)
{
    float alpha = m->alpha;
    float3 wh = GGX_SampleVisibleNormal(wo, alpha, u);
    float wo_dot_wh = Dot3(wo, wh);
    *wi = 2.0f * wo_dot_wh * wh - wo;
    if (!(wo.z > 0.0f && wi->z > 0.0f)) {
        *pdfW = 0.0f;
        return (float3)(0.0f);
    }
    float lambda_o = GGX_Lambda(wo, alpha);
    float lambda_i = GGX_Lambda(*wi, alpha);
    *pdfW = GGX_D(wh, alpha) / ((1.0f + lambda_o) * 4.0f * wo.z);
    float3 fresnel = Fresnel_Conductor(wo_dot_wh, Load3(m->eta), Load3(m->k));
    return fresnel * ((1.0f + lambda_o) / (1.0f + lambda_o + lambda_i));
}

// ----------------------------------------------------------------------------- dielectric

// Smooth dielectric: reflect with probability F, else refract (Snell). pdfW is the discrete
// probability of the choice; the refracted weight carries the radiance scaling 1 / eta'^2.
CL_INLINE float3 Dielectric_Sample(__global const Material *m, float3 wo, float u, float3 *wi,
                                   float *pdfW)
{
    float eta = m->eta[0];
    float cos_o = wo.z;
    float fresnel = Fresnel_Dielectric(cos_o, eta);
    if (u < fresnel) {
        *wi = (float3)(-wo.x, -wo.y, wo.z);
        *pdfW = fresnel;
        return (float3)(1.0f);
    }
    float eta_rel = cos_o > 0.0f ? eta : 1.0f / eta;
    float sin2_t = (1.0f - cos_o * cos_o) / (eta_rel * eta_rel);
    float cos_t = Sqrt(Fmax(0.0f, 1.0f - sin2_t));
    *wi = (float3)(-wo.x / eta_rel, -wo.y / eta_rel, cos_o > 0.0f ? -cos_t : cos_t);
    *pdfW = 1.0f - fresnel;
    return (float3)(1.0f / (eta_rel * eta_rel));
}

// ----------------------------------------------------------------------------- dispatch

CL_INLINE bool BSDF_IsSpecular(__global const Material *m)
{
    return m->type == MATERIAL_DIELECTRIC;
}

CL_INLINE float3 BSDF_Eval(__global const Material *m, float3 wo, float3 wi)
{
    switch (m->type) {
    case MATERIAL_DIFFUSE:
        return Diffuse_Eval(m, wo, wi);
    case MATERIAL_ROUGHCONDUCTOR:
        return Conductor_Eval(m, wo, wi);
    default:
        return (float3)(0.0f);
    }
}

CL_INLINE float BSDF_PdfW(__global const Material *m, float3 wo, float3 wi)
{
    switch (m->type) {
    case MATERIAL_DIFFUSE:
        return Diffuse_PdfW(wo, wi);
    case MATERIAL_ROUGHCONDUCTOR:
        return Conductor_PdfW(m, wo, wi);
    default:
        return 0.0f;
    }
}

// Sample wi for wo with uniforms u; returns the weight f |cos wi| / pdfW (zero on failure).
CL_INLINE float3 BSDF_Sample(__global const Material *m, float3 wo, float3 u, float3 *wi,
                             float *pdfW)
{
    switch (m->type) {
    case MATERIAL_DIFFUSE:
        return Diffuse_Sample(m, wo, u.xy, wi, pdfW);
    case MATERIAL_ROUGHCONDUCTOR:
        return Conductor_Sample(m, wo, u.xy, wi, pdfW);
    case MATERIAL_DIELECTRIC:
        return Dielectric_Sample(m, wo, u.z, wi, pdfW);
    default:
        *wi = (float3)(0.0f, 0.0f, 1.0f);
        *pdfW = 0.0f;
        return (float3)(0.0f);
    }
}

#endif
