// Exact Poisson sampling on the device, one pixel per work-item, from that pixel's Philox stream
// (sample = RNG_PIXEL_STREAM, dimension = draw index, so a redraw or a rejection loop never
// reuses numbers). No normal approximation at any mean.
//   mean < 10 : Knuth's product of uniforms (about mean + 1 uniforms).
//   mean >= 10: Hoermann's PTRS transformed rejection (Insurance: Math. Econ. 12, 1993),
//               exact for mean >= 10, accepting about 90 % of proposals.
// The log-pmf is evaluated in float with Stirling's series written around k = mean so that
// no large terms cancel; this keeps it accurate to ~1e-6 up to means of 2^20 and beyond.
#ifndef CLRENDER_POISSON_H
#define CLRENDER_POISSON_H

#include "rng.h"

#define POISSON_PTRS_MIN_MEAN 10.0f
// A guard, not a tuning knob: the chance of 4096 rejected PTRS proposals is below 1e-4000.
#define POISSON_MAX_PROPOSALS 4096u

// log(mean^k e^-mean / k!), accurate when k and mean are large and close.
inline float Poisson_LogPmf(uint k, float mean)
{
    if (k < 10u)
        return (float)k * log(mean) - mean - lgamma((float)k + 1.0f);
    float kf = (float)k;
    float d = (mean - kf) / kf;
    // k log(mean/k) + k - mean = k (log1p(d) - d); then Stirling's 0.5 log(2 pi k) + 1/(12k) - ...
    float inv_k = 1.0f / kf;
    float stirling = 1.0f / 12.0f * inv_k - 1.0f / 360.0f * inv_k * inv_k * inv_k;
    return kf * (log1p(d) - d) - 0.5f * log(2.0f * M_PI_F * kf) - stirling;
}

inline uint Poisson_Knuth(float mean, uint seed, uint pixel, uint redraw)
{
    float limit = exp(-mean);
    float product = 1.0f;
    uint k = 0u;
    for (uint block = 0u; block < POISSON_MAX_PROPOSALS; ++block) {
        float4 u = Rng_Uniform4(seed, pixel, RNG_PIXEL_STREAM, block, redraw);
        float us[4] = {u.x, u.y, u.z, u.w};
        for (int j = 0; j < 4; ++j) {
            product *= us[j];
            if (product <= limit)
                return k;
            ++k;
        }
    }
    return k;
}

inline uint Poisson_Ptrs(float mean, uint seed, uint pixel, uint redraw)
{
    // Constants of the transformed-rejection hat (Hoermann 1993, algorithm PTRS).
    float smu = sqrt(mean);
    float b = 0.931f + 2.53f * smu;
    float a = -0.059f + 0.02483f * b;
    float log_inv_alpha = log(1.1239f + 1.1328f / (b - 3.4f));
    float vr = 0.9277f - 3.6224f / (b - 2.0f);
    for (uint block = 0u; block < POISSON_MAX_PROPOSALS; ++block) {
        float4 r = Rng_Uniform4(seed, pixel, RNG_PIXEL_STREAM, block, redraw);
        // Two proposals (U, V) per Philox block.
        for (int pair = 0; pair < 2; ++pair) {
            float u = (pair == 0 ? r.x : r.z) - 0.5f;
            float v = pair == 0 ? r.y : r.w;
            float us = 0.5f - fabs(u);
            float kf = floor((2.0f * a / us + b) * u + mean + 0.43f);
            if (us >= 0.07f && v <= vr)
                return (uint)kf;
            if (kf < 0.0f || (us < 0.013f && v > us))
                continue;
            float log_hat = log(v) + log_inv_alpha - log(a / (us * us) + b);
            if (log_hat <= Poisson_LogPmf((uint)kf, mean))
                return (uint)kf;
        }
    }
    return (uint)floor(mean);
}

inline uint Poisson_Sample(float mean, uint seed, uint pixel, uint redraw)
{
    return mean < POISSON_PTRS_MIN_MEAN ? Poisson_Knuth(mean, seed, pixel, redraw)
                                        : Poisson_Ptrs(mean, seed, pixel, redraw);
}

#endif
