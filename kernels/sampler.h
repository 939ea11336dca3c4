// The samplers of a path's dimensions: every value a pure function of (seed, pixel, sample,
// dimension, redraw), so an image is the same whatever the tiling.
//
//   independent  Philox uniforms (rng.h);
//   stratified   jittered strata: n strata for a 1D dimension, a sqrt(n) x sqrt(n) grid for a
//                pair, each dimension (pair) with its own random permutation of the strata over
//                the samples (pbrt-v4's StratifiedSampler, Mitsuba 3's stratified);
//   sobol        padded Owen-scrambled Sobol: each dimension (pair) is Sobol dimension 0 (and 1)
//                under its own nested scramble, at its own nested shuffle of the sample index
//                (Burley, "Practical Hash-based Owen Scrambling", JCGT 9(4), 2020);
//   zsobol       one global Owen-scrambled Sobol sequence over the image, indexed by the
//                pixels' Morton order with its base-4 digits randomly permuted per dimension,
//                then the sample (pbrt-v4's ZSobolSampler after Ahmed and Wonka, SIGGRAPH Asia
//                2020), so error spreads as blue noise across pixels.
//
// Dimension layout (the low-discrepancy dimensions; a pair is drawn together):
//   0, 1           the pixel position (x, y)
//   b = 2 + 7 d    bounce d: b emitter choice, b+1 b+2 emitter point, b+3 BSDF lobe choice,
//                  b+4 b+5 BSDF direction, b+6 Russian roulette
// Every bounce draws all seven, used or not, so a dimension always means the same thing.
// The Philox slots (independent values, the stratified sampler's jitter): dimension 0 the pixel
// position, 1 + 2 d (emitter choice, emitter point u, v, roulette), 2 + 2 d (direction u, v,
// lobe), as before the low-discrepancy samplers existed: the independent sampler's images are
// unchanged. Keys: one Philox block of (seed, pixel, redraw) at sample RNG_PIXEL_STREAM,
// dimension SAMPLER_KEY_DIMENSION (Poisson draws use the low dimensions of that stream), hashed
// with each dimension.
#ifndef CLRENDER_SAMPLER_H
#define CLRENDER_SAMPLER_H

#include "rng.h"
#include "lowdiscrepancy.h"

#define PATHS_INDEPENDENT 0
#define PATHS_STRATIFIED 1
#define PATHS_SOBOL 2
#define PATHS_ZSOBOL 3

#define SAMPLER_BOUNCE_DIMENSIONS 7u
#define SAMPLER_KEY_DIMENSION 0x80000000u
#define SAMPLER_SHIFT_DIMENSION 0x7FFFFFFFu
// zsobol's keys belong to the whole image, not to a pixel (pixel indices stay below this).
#define SAMPLER_IMAGE_PIXEL 0xFFFFFFFFu
// The largest float below 1 and below 1/2: values stay strictly inside their ranges.
#define SAMPLER_BELOW_ONE 0x1.fffffep-1f
#define SAMPLER_BELOW_HALF 0x1.fffffep-2f

typedef struct {
    int kind; // PATHS_*
    uint seed, pixel, sample, redraw;
    uint count;        // stratified: samples per pixel n, the strata of a 1D dimension
    uint strata;       // stratified: sqrt(n), the side of a pair's grid
    uint zsobol_index; // zsobol: the pixel's Morton code, then log2(n) bits of the sample index
    uint zsobol_bits;  // zsobol: significant bits of zsobol_index
    uint2 key;         // Philox bits of (seed, pixel or image, redraw): the dimensions' keys
} Sampler;

// The random numbers of one bounce (see the dimension layout above).
typedef struct {
    float emitter_choice;
    float2 emitter_point;
    float lobe;
    float2 direction;
    float roulette;
} BounceSamples;

// zsobol_log2_count: log2(n); zsobol_bits: 2 log2(padded resolution) + log2(n), at most 32.
inline Sampler Sampler_Make(int kind, uint seed, uint pixel, uint sample, uint redraw,
                            uint count, uint strata, uint image_width, uint zsobol_log2_count,
                            uint zsobol_bits)
{
    Sampler s = {kind, seed, pixel, sample, redraw, count, strata, 0u, 0u, (uint2)(0u)};
    // One Philox block per sample for the keys of all its dimensions (zsobol's: the image's)
    if (kind != PATHS_INDEPENDENT) {
        uint owner = kind == PATHS_ZSOBOL ? SAMPLER_IMAGE_PIXEL : pixel;
        s.key = Rng_Bits4(seed, owner, RNG_PIXEL_STREAM, SAMPLER_KEY_DIMENSION, redraw).xy;
    }
    if (kind == PATHS_ZSOBOL) {
        uint morton = LD_Morton2(pixel % image_width, pixel / image_width);
        s.zsobol_index = (morton << zsobol_log2_count) | sample;
        s.zsobol_bits = zsobol_bits;
    }
    return s;
}

// 32 well-mixed bits of x (an xorshift-multiply finaliser; C. Wellons' hash-prospector form).
inline uint Sampler_Hash(uint x)
{
    x ^= x >> 16;
    x *= 0x21f0aaadu;
    x ^= x >> 15;
    x *= 0x735a2d97u;
    x ^= x >> 15;
    return x;
}

// Four keys of one dimension (pair): permutation or shuffle key, rotation, two Owen seeds;
// hashes of the sample's Philox key and the dimension (cheaper than a Philox block each).
// zsobol's belong to the image (and the redraw: redraw r of every pixel is one sequence).
inline uint4 Sampler_Keys(const Sampler *s, uint dim)
{
    uint h = Sampler_Hash(s->key.x ^ Sampler_Hash(dim + s->key.y));
    return (uint4)(h, Sampler_Hash(h ^ 0x68e31da4u), Sampler_Hash(h ^ 0xb5297a4du),
                   Sampler_Hash(h ^ 0x1b56c4e9u));
}

// The sample's index into the dimension's Sobol sequence. sobol: a nested shuffle of the
// sample index (the pixel's first 2^m samples stay one aligned block of 2^m indices). zsobol:
// the image-wide index with each base-4 digit permuted by a hash of the digits above it, so
// the four quarters of every Morton block (2 x 2 pixels, their quads, ...; the samples of a
// pixel) trade places at random, and a pixel's samples stay one aligned block.
inline uint Sampler_SobolIndex(const Sampler *s, uint key)
{
    if (s->kind != PATHS_ZSOBOL)
        return LD_OwenScramble(s->sample, key);
    uint index = s->zsobol_index;
    uint permuted = 0u;
    int shift = (int)s->zsobol_bits - 2;
    for (; shift >= 0; shift -= 2) {
        // The digits above, tagged with their count so that levels do not share hashes
        uint higher = shift >= 30 ? 0u : index >> (uint)(shift + 2);
        uint hash = Sampler_Hash((higher ^ key) + (uint)shift * 0x9E3779B9u);
        permuted |= LD_PermuteDigit4(hash, (index >> (uint)shift) & 3u) << (uint)shift;
    }
    // An odd bit count leaves the last binary digit, flipped by a hash of the rest
    if (shift == -1)
        permuted |= (index ^ Sampler_Hash(((index >> 1) ^ key) + 0xFFFFFFFFu * 0x9E3779B9u)) & 1u;
    return permuted;
}

// Sobol dimension 0 at the index, Owen-scrambled (the two bit reversals cancel).
inline uint Sampler_Sobol1(const Sampler *s, uint dim)
{
    uint4 keys = Sampler_Keys(s, dim);
    uint index = Sampler_SobolIndex(s, keys.x);
    return LD_ReverseBits(LD_NestedHash(index, keys.z));
}

// Sobol dimensions 0 and 1 at one index, each Owen-scrambled with its own seed.
inline uint2 Sampler_Sobol2(const Sampler *s, uint dim)
{
    uint4 keys = Sampler_Keys(s, dim);
    uint index = Sampler_SobolIndex(s, keys.x);
    return (uint2)(LD_ReverseBits(LD_NestedHash(index, keys.z)),
                   LD_ReverseBits(LD_NestedHash(Sobol_Dimension1Reversed(index), keys.w)));
}

// Stratum of the sample among n for a 1D dimension, jittered by u in (0, 1).
inline float Sampler_Stratified1(const Sampler *s, uint dim, float u)
{
    uint4 keys = Sampler_Keys(s, dim);
    uint stratum = LD_PermutationElement(s->sample, s->count, keys.x, keys.y);
    float v = ((float)stratum + u) / (float)s->count;
    return v < SAMPLER_BELOW_ONE ? v : SAMPLER_BELOW_ONE;
}

// Cell of the sample in the pair's sqrt(n) x sqrt(n) grid, jittered by u in (0, 1)^2.
inline float2 Sampler_Stratified2(const Sampler *s, uint dim, float2 u)
{
    uint4 keys = Sampler_Keys(s, dim);
    uint stratum = LD_PermutationElement(s->sample, s->count, keys.x, keys.y);
    float2 cell = (float2)((float)(stratum % s->strata), (float)(stratum / s->strata));
    float2 v = (cell + u) / (float)s->strata;
    return (float2)(v.x < SAMPLER_BELOW_ONE ? v.x : SAMPLER_BELOW_ONE,
                    v.y < SAMPLER_BELOW_ONE ? v.y : SAMPLER_BELOW_ONE);
}

// The sample's position in the pixel W = (-1/2, 1/2)^2 (dimensions 0 and 1).
inline float2 Sampler_Position(const Sampler *s)
{
    if (s->kind == PATHS_SOBOL || s->kind == PATHS_ZSOBOL) {
        uint2 bits = Sampler_Sobol2(s, 0u);
        return (float2)(Rng_ToCentered(bits.x), Rng_ToCentered(bits.y));
    }
    if (s->kind == PATHS_STRATIFIED) {
        float4 u = Rng_Uniform4(s->seed, s->pixel, s->sample, 0u, s->redraw);
        // Below 1 stays below 1/2 once centred; a tiny value may round to -1/2: keep it inside
        float2 v = Sampler_Stratified2(s, 0u, u.xy) - 0.5f;
        return (float2)(v.x > -SAMPLER_BELOW_HALF ? v.x : -SAMPLER_BELOW_HALF,
                        v.y > -SAMPLER_BELOW_HALF ? v.y : -SAMPLER_BELOW_HALF);
    }
    return Rng_Centered2(s->seed, s->pixel, s->sample, 0u, s->redraw);
}

// The seven numbers of bounce `depth` (dimensions 2 + 7 depth ... 8 + 7 depth).
inline BounceSamples Sampler_Bounce(const Sampler *s, uint depth)
{
    BounceSamples b;
    uint dim = 2u + SAMPLER_BOUNCE_DIMENSIONS * depth;
    if (s->kind == PATHS_SOBOL || s->kind == PATHS_ZSOBOL) {
        b.emitter_choice = Rng_ToUnit(Sampler_Sobol1(s, dim));
        uint2 point = Sampler_Sobol2(s, dim + 1u);
        b.emitter_point = (float2)(Rng_ToUnit(point.x), Rng_ToUnit(point.y));
        b.lobe = Rng_ToUnit(Sampler_Sobol1(s, dim + 3u));
        uint2 direction = Sampler_Sobol2(s, dim + 4u);
        b.direction = (float2)(Rng_ToUnit(direction.x), Rng_ToUnit(direction.y));
        b.roulette = Rng_ToUnit(Sampler_Sobol1(s, dim + 6u));
        return b;
    }
    float4 u_light = Rng_Uniform4(s->seed, s->pixel, s->sample, 1u + 2u * depth, s->redraw);
    float4 u_bsdf = Rng_Uniform4(s->seed, s->pixel, s->sample, 2u + 2u * depth, s->redraw);
    if (s->kind == PATHS_STRATIFIED) {
        b.emitter_choice = Sampler_Stratified1(s, dim, u_light.x);
        b.emitter_point = Sampler_Stratified2(s, dim + 1u, u_light.yz);
        b.lobe = Sampler_Stratified1(s, dim + 3u, u_bsdf.z);
        b.direction = Sampler_Stratified2(s, dim + 4u, u_bsdf.xy);
        b.roulette = Sampler_Stratified1(s, dim + 6u, u_light.w);
        return b;
    }
    b.emitter_choice = u_light.x;
    b.emitter_point = u_light.yz;
    b.lobe = u_bsdf.z;
    b.direction = u_bsdf.xy;
    b.roulette = u_light.w;
    return b;
}

// A position moved by `shift` on the torus W, strictly inside W.
inline float2 Sampler_ShiftOnTorus(float2 position, float2 shift)
{
    float2 shifted = position + shift;
    shifted.x = shifted.x >= 0.5f ? shifted.x - 1.0f : shifted.x;
    shifted.y = shifted.y >= 0.5f ? shifted.y - 1.0f : shifted.y;
    // Rounding may land on the edge -1/2: keep the point strictly inside W
    shifted.x = shifted.x > -SAMPLER_BELOW_HALF ? shifted.x : -SAMPLER_BELOW_HALF;
    shifted.y = shifted.y > -SAMPLER_BELOW_HALF ? shifted.y : -SAMPLER_BELOW_HALF;
    return shifted;
}

// The shift of the pixel's whole point set, one per (pixel, redraw).
inline float2 Sampler_ShiftOf(uint seed, uint pixel, uint redraw)
{
    return Rng_Uniform4(seed, pixel, RNG_PIXEL_STREAM, SAMPLER_SHIFT_DIMENSION, redraw).xy;
}

// A toroidal (Cranley-Patterson) shift of the pixel's whole point set, one per (pixel, redraw):
// torus Voronoi cell areas do not change under it, so pvor stays unbiased over any point set.
inline float2 Sampler_ToroidalShift(uint seed, uint pixel, uint redraw, float2 position)
{
    return Sampler_ShiftOnTorus(position, Sampler_ShiftOf(seed, pixel, redraw));
}

#endif
