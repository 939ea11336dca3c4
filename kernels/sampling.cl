// Per-pixel sample sets in pixel-local coordinates, W = [-1/2, 1/2]^2.
//
// A launch covers a list of pixels (a tile, or the pixels to redraw after a rejection), each
// given by its global index and its redraw number. Two passes:
//   count_samples: how many traced samples each pixel gets (n, or N ~ Poisson(n) for SPPP);
//   (the host turns the counts into offsets with a prefix sum)
//   fill_samples:  one work-item per output slot writes one position.
// Output layout, one contiguous float2 buffer: all traced samples, pixel by pixel
// (traced_offsets), then all auxiliary nuclei, pixel by pixel (n_aux each). Auxiliary nuclei are
// never traced; they only shape Voronoi cells.
#include "poisson.h"

#define SAMPLER_UNIFORM 0
#define SAMPLER_STRATIFIED 1
#define SAMPLER_SPPP 2

__kernel void count_samples(uint pixel_count, uint seed, int sampler, uint n, float mean,
                            __global const uint *pixels, __global const uint *redraws,
                            __global uint *counts)
{
    uint p = get_global_id(0);
    if (p >= pixel_count)
        return;
    counts[p] = sampler == SAMPLER_SPPP ? poisson_sample(mean, seed, pixels[p], redraws[p]) : n;
}

// The pixel whose [offsets[p], offsets[p+1]) range holds slot i (binary search).
inline uint owner_pixel(__global const uint *offsets, uint pixel_count, uint i)
{
    uint lo = 0u, hi = pixel_count;
    while (hi - lo > 1u) {
        uint mid = (lo + hi) / 2u;
        if (offsets[mid] <= i)
            lo = mid;
        else
            hi = mid;
    }
    return lo;
}

// Jittered strata: sample s falls in stratum (s mod m, s div m) of an m x m grid.
inline float2 stratified_position(uint s, uint strata, float2 jitter)
{
    float2 cell = (float2)((float)(s % strata), (float)(s / strata));
    // Rounding may land on the edge: keep the point strictly inside W like the other samplers.
    return clamp((cell + jitter) / (float)strata - 0.5f, -0x1.fffffep-2f, 0x1.fffffep-2f);
}

// A point uniform by area over the strip W' \ W: top and bottom rectangles (1 + 2 eps) x eps
// hold the corners, left and right rectangles are 1 x eps; one is picked in proportion to area.
inline float2 strip_position(float eps, float4 u)
{
    float long_side = 1.0f + 2.0f * eps;
    float area_tb = long_side * eps;
    float pick = u.x * (2.0f * area_tb + 2.0f * eps);
    float along = u.y;
    float across = u.z * eps;
    if (pick < area_tb)
        return (float2)(-0.5f - eps + along * long_side, -0.5f - across);
    if (pick < 2.0f * area_tb)
        return (float2)(-0.5f - eps + along * long_side, 0.5f + across);
    if (pick < 2.0f * area_tb + eps)
        return (float2)(-0.5f - across, -0.5f + along);
    return (float2)(0.5f + across, -0.5f + along);
}

__kernel void fill_samples(uint pixel_count, uint seed, int sampler, uint strata, float eps,
                           uint n_aux, uint traced_total, __global const uint *pixels,
                           __global const uint *redraws, __global const uint *traced_offsets,
                           __global float2 *positions)
{
    uint i = get_global_id(0);
    if (i >= traced_total + n_aux * pixel_count)
        return;
    // Auxiliary nucleus j of pixel p: its own sample index range, so it never shares numbers.
    if (i >= traced_total) {
        uint p = (i - traced_total) / n_aux;
        uint j = (i - traced_total) % n_aux;
        float4 u = rng_uniform4(seed, pixels[p], RNG_AUX_BASE + j, 0u, redraws[p]);
        positions[i] = strip_position(eps, u);
        return;
    }
    // Traced sample s of pixel p: dimension 0 of its stream is its position.
    uint p = owner_pixel(traced_offsets, pixel_count, i);
    uint s = i - traced_offsets[p];
    if (sampler == SAMPLER_STRATIFIED) {
        float4 u = rng_uniform4(seed, pixels[p], s, 0u, redraws[p]);
        positions[i] = stratified_position(s, strata, u.xy);
    } else {
        positions[i] = rng_centered2(seed, pixels[p], s, 0u, redraws[p]);
    }
}
