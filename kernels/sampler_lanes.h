// The path samplers (kernels/sampler.h, lowdiscrepancy.h, rng.h) on vector lanes, one sample a
// lane of vfloat / vuint (simd_lanes.h): the same integer operations, so every lane's bits are
// its scalar Sampler's. For the kernels that run SIMD_WIDTH samples per work-item: the paths'
// bounce numbers (kernels/trace_simd.cl) and the pixel positions of the path samplers
// (kernels/sampling.cl fill_traced_from_sampler).
#ifndef CLRENDER_SAMPLER_LANES_H
#define CLRENDER_SAMPLER_LANES_H

#include "sampler.h"
#include "simd_lanes.h"

// Rng_ToUnit on lanes: (k + 1/2) 2^-23 from the top 23 bits, exactly.
SIMD_FN vfloat V_ToUnit(vuint bits)
{
    return (TO_VFLOAT(bits >> 9) + 0.5f) * 0x1p-23f;
}

// Rng_ToCentered on lanes: (k + 1/2) 2^-24 - 1/2 from the top 24 bits, exactly.
SIMD_FN vfloat V_ToCentered(vuint bits)
{
    return (TO_VFLOAT(TO_VINT(bits >> 8) - 0x800000) + 0.5f) * 0x1p-24f;
}

// Rng_Uniform4 on lanes: Philox4x32-10 of counter (sample, dim, redraw, 0), key (seed, pixel),
// each lane at its own dimension.
SIMD_FN void V_Uniform4Lanes(uint seed, vuint pixel, vuint sample, vuint dim, vuint redraw,
                             vfloat *u0, vfloat *u1, vfloat *u2, vfloat *u3)
{
    vuint c0 = sample;
    vuint c1 = dim;
    vuint c2 = redraw;
    vuint c3 = (vuint)0u;
    vuint k0 = (vuint)seed;
    vuint k1 = pixel;
#pragma unroll
    for (int round = 0; round < 10; ++round) {
        vulong product0 = TO_VULONG(c0) * (vulong)PHILOX_M0;
        vulong product1 = TO_VULONG(c2) * (vulong)PHILOX_M1;
        vuint n0 = TO_VUINT(product1 >> 32) ^ c1 ^ k0;
        vuint n1 = TO_VUINT(product1);
        vuint n2 = TO_VUINT(product0 >> 32) ^ c3 ^ k1;
        vuint n3 = TO_VUINT(product0);
        c0 = n0;
        c1 = n1;
        c2 = n2;
        c3 = n3;
        k0 += PHILOX_W0;
        k1 += PHILOX_W1;
    }
    *u0 = V_ToUnit(c0);
    *u1 = V_ToUnit(c1);
    *u2 = V_ToUnit(c2);
    *u3 = V_ToUnit(c3);
}

// Rng_Uniform4 on lanes, every lane at dimension dim.
SIMD_FN void V_Uniform4(uint seed, vuint pixel, vuint sample, uint dim, vuint redraw, vfloat *u0,
                        vfloat *u1, vfloat *u2, vfloat *u3)
{
    V_Uniform4Lanes(seed, pixel, sample, (vuint)dim, redraw, u0, u1, u2, u3);
}

// Sampler_Hash
SIMD_FN vuint V_Hash(vuint x)
{
    x ^= x >> 16;
    x *= 0x21f0aaadu;
    x ^= x >> 15;
    x *= 0x735a2d97u;
    x ^= x >> 15;
    return x;
}

// LD_ReverseBits
SIMD_FN vuint V_ReverseBits(vuint x)
{
    x = (x << 16) | (x >> 16);
    x = ((x & 0x00FF00FFu) << 8) | ((x >> 8) & 0x00FF00FFu);
    x = ((x & 0x0F0F0F0Fu) << 4) | ((x >> 4) & 0x0F0F0F0Fu);
    x = ((x & 0x33333333u) << 2) | ((x >> 2) & 0x33333333u);
    x = ((x & 0x55555555u) << 1) | ((x >> 1) & 0x55555555u);
    return x;
}

// LD_NestedHash
SIMD_FN vuint V_NestedHash(vuint x, vuint seed)
{
    x += seed;
    x ^= x * 0x6c50b47cu;
    x ^= x * 0xb82f1e52u;
    x ^= x * 0xc7afe638u;
    x ^= x * 0x8d22f6e6u;
    return x;
}

// Sobol_Dimension1Reversed
SIMD_FN vuint V_Dimension1Reversed(vuint index)
{
    index ^= (index >> 1) & 0x55555555u;
    index ^= (index >> 2) & 0x33333333u;
    index ^= (index >> 4) & 0x0F0F0F0Fu;
    index ^= (index >> 8) & 0x00FF00FFu;
    index ^= (index >> 16) & 0x0000FFFFu;
    return index;
}

// LD_PermuteDigit4: which = 24 hash / 2^32 from 16-bit halves (exact: the high half's product
// is an integer), and LD_DIGIT_PERMUTATIONS as six words of four bytes, picked by one vpermd
// (AVX-512; elsewhere by selects) instead of a gather.
SIMD_FN vuint V_PermuteDigit4(vuint hash, vuint digit)
{
    vuint which = ((hash >> 16) * 24u + (((hash & 0xFFFFu) * 24u) >> 16)) >> 16;
    vuint word = which >> 2;
#if defined(__AVX512F__) && SIMD_WIDTH == 16 && !defined(SIMD_PORTABLE)
    const int16 words = (int16)(0x78d8b4e4, 0xb1e16c9c, 0x2d8d39c9, 0x36c672d2, 0x63931e4e,
                                0x1b4b2787, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0);
    vuint table = AS_VUINT(__builtin_ia32_permvarsi512(words, as_int16(word)));
#else
    vuint table = word == 0u ? (vuint)0x78d8b4e4u : (vuint)0xb1e16c9cu;
    table = word == 2u ? (vuint)0x2d8d39c9u : table;
    table = word == 3u ? (vuint)0x36c672d2u : table;
    table = word == 4u ? (vuint)0x63931e4eu : table;
    table = word == 5u ? (vuint)0x1b4b2787u : table;
#endif
    return (table >> (((which & 3u) << 3) + 2u * digit)) & 3u;
}

// Each lane's Sampler fields that the stratified, sobol and zsobol samplers read.
typedef struct {
    int kind;           // PATHS_*
    uint zsobol_bits;   // the launch's
    vuint key_x, key_y; // Sampler.key
    vuint index;        // zsobol: Sampler.zsobol_index; the others: Sampler.sample
} SamplerLanes;

// Sampler_SobolIndex
SIMD_FN vuint V_SobolIndex(const SamplerLanes *s, vuint key)
{
    if (s->kind != PATHS_ZSOBOL)
        return V_ReverseBits(V_NestedHash(V_ReverseBits(s->index), key));
    vuint index = s->index;
    vuint permuted = (vuint)0u;
    int shift = (int)s->zsobol_bits - 2;
    for (; shift >= 0; shift -= 2) {
        vuint higher = shift >= 30 ? (vuint)0u : index >> (uint)(shift + 2);
        vuint hash = V_Hash((higher ^ key) + (uint)shift * 0x9E3779B9u);
        permuted |= V_PermuteDigit4(hash, (index >> (uint)shift) & 3u) << (uint)shift;
    }
    if (shift == -1)
        permuted |= (index ^ V_Hash(((index >> 1) ^ key) + 0xFFFFFFFFu * 0x9E3779B9u)) & 1u;
    return permuted;
}

// The bits of Sampler_Sobol1 (y null) and Sampler_Sobol2 of dimension dim (each lane its own:
// regenerated paths' lanes are at different depths).
SIMD_FN void V_SobolBits(const SamplerLanes *s, vuint dim, vuint *x, vuint *y)
{
    // Sampler_Keys: .x, .z and .w (.y is the stratified sampler's)
    vuint h = V_Hash(s->key_x ^ V_Hash(dim + s->key_y));
    vuint index = V_SobolIndex(s, h);
    *x = V_ReverseBits(V_NestedHash(index, V_Hash(h ^ 0xb5297a4du)));
    if (y)
        *y = V_ReverseBits(V_NestedHash(V_Dimension1Reversed(index), V_Hash(h ^ 0x1b56c4e9u)));
}

// Sampler_Sobol1 (y null) and Sampler_Sobol2 of dimension dim, as unit floats (Rng_ToUnit).
SIMD_FN void V_Sobol(const SamplerLanes *s, vuint dim, vfloat *x, vfloat *y)
{
    vuint bits, bits1;
    V_SobolBits(s, dim, &bits, y ? &bits1 : 0);
    *x = V_ToUnit(bits);
    if (y)
        *y = V_ToUnit(bits1);
}

// Sampler_Bounce of the sobol and zsobol samplers on lanes, each lane at its own depth.
SIMD_FN void V_SobolBounce(const SamplerLanes *s, vuint depth, vfloat *u_choice,
                           vfloat *u_point0, vfloat *u_point1, vfloat *u_lobe, vfloat *u_dir0,
                           vfloat *u_dir1, vfloat *u_roulette)
{
    vuint dim = 2u + SAMPLER_BOUNCE_DIMENSIONS * depth;
    V_Sobol(s, dim, u_choice, 0);
    V_Sobol(s, dim + 1u, u_point0, u_point1);
    V_Sobol(s, dim + 3u, u_lobe, 0);
    V_Sobol(s, dim + 4u, u_dir0, u_dir1);
    V_Sobol(s, dim + 6u, u_roulette, 0);
}

// Division by a divisor shared by the lanes, exact for every 32-bit dividend (Granlund and
// Montgomery, "Division by invariant integers using multiplication", PLDI 1994, figure 4.1):
// q = (t + ((n - t) >> sh1)) >> sh2 with t the high half of m n. Vector integer division has no
// instruction: the compiler would divide lane by lane.
typedef struct {
    uint m, sh1, sh2;
} Divisor;

CL_INLINE Divisor Divisor_Make(uint d)
{
    uint l = 0u; // ceil(log2 d)
    while (l < 32u && (1ul << l) < (ulong)d)
        ++l;
    Divisor v;
    v.m = (uint)((((1ul << l) - (ulong)d) << 32) / (ulong)d + 1ul);
    v.sh1 = l < 1u ? l : 1u;
    v.sh2 = l > 1u ? l - 1u : 0u;
    return v;
}

SIMD_FN vuint V_Divide(vuint n, Divisor d)
{
    vuint t = TO_VUINT((TO_VULONG(n) * (ulong)d.m) >> 32);
    return (t + ((n - t) >> d.sh1)) >> d.sh2;
}

// LD_PermutationElement of every lane for the shared n (mask and half_bits: its range's, as
// there): the cycle walk goes on in the lanes still above n.
SIMD_FN vuint V_PermutationElement(vuint i, uint n, Divisor by_n, uint mask, uint half_bits,
                                   vuint key, vuint rotation)
{
    i = i < n ? i : i - V_Divide(i, by_n) * n;
    vint walking = (vint)(-1);
    do {
        vuint k = ((i ^ key) * 0x9E3779B1u) & mask;
        k ^= k >> half_bits;
        k = ((k + (key >> 16)) * (key | 1u)) & mask;
        k ^= k >> 1;
        k = (k * 0x85EBCA77u) & mask;
        k ^= k >> half_bits;
        i = walking ? k : i;
        walking &= i >= n;
    } while (V_Bits(walking) != 0u);
    i += rotation - V_Divide(rotation, by_n) * n;
    return i >= n ? i - n : i;
}

// The stratified sampler's launch constants (Sampler.count and .strata, shared by the lanes).
typedef struct {
    uint count, strata, mask, half_bits;
    Divisor by_count, by_strata;
} Strata;

CL_INLINE Strata Strata_Make(uint count, uint strata)
{
    Strata s;
    s.count = count;
    s.strata = strata;
    uint mask = count - 1u; // LD_PermutationElement's
    mask |= mask >> 1;
    mask |= mask >> 2;
    mask |= mask >> 4;
    mask |= mask >> 8;
    mask |= mask >> 16;
    s.mask = mask;
    s.half_bits = 1u;
    for (uint m = mask; m > 1u; m >>= 2)
        ++s.half_bits;
    s.by_count = Divisor_Make(count);
    s.by_strata = Divisor_Make(strata);
    return s;
}

// The stratum of every lane's sample in its dimension dim (Sampler_Keys .x and .y).
SIMD_FN vuint V_Stratum(const SamplerLanes *s, const Strata *st, vuint dim)
{
    vuint h = V_Hash(s->key_x ^ V_Hash(dim + s->key_y));
    return V_PermutationElement(s->index, st->count, st->by_count, st->mask, st->half_bits, h,
                                V_Hash(h ^ 0x68e31da4u));
}

// Sampler_Stratified1
SIMD_FN vfloat V_Stratified1(const SamplerLanes *s, const Strata *st, vuint dim, vfloat u)
{
    vuint stratum = V_Stratum(s, st, dim);
    vfloat v = (TO_VFLOAT(stratum) + u) / (float)st->count;
    return v < SAMPLER_BELOW_ONE ? v : (vfloat)(SAMPLER_BELOW_ONE);
}

// Sampler_Stratified2: u0 and u1 in, the pair out.
SIMD_FN void V_Stratified2(const SamplerLanes *s, const Strata *st, vuint dim, vfloat *u0,
                           vfloat *u1)
{
    vuint stratum = V_Stratum(s, st, dim);
    vuint row = V_Divide(stratum, st->by_strata);
    vfloat v0 = (TO_VFLOAT(stratum - row * st->strata) + *u0) / (float)st->strata;
    vfloat v1 = (TO_VFLOAT(row) + *u1) / (float)st->strata;
    *u0 = v0 < SAMPLER_BELOW_ONE ? v0 : (vfloat)(SAMPLER_BELOW_ONE);
    *u1 = v1 < SAMPLER_BELOW_ONE ? v1 : (vfloat)(SAMPLER_BELOW_ONE);
}

// Sampler_Bounce of the stratified sampler on lanes, each lane at its own depth (the jitter:
// V_Uniform4Lanes as Sampler_Bounce's Rng_Uniform4).
SIMD_FN void V_StratifiedBounce(const SamplerLanes *s, const Strata *st, uint seed, vuint pixel,
                                vuint redraw, vuint depth, vfloat *u_choice, vfloat *u_point0,
                                vfloat *u_point1, vfloat *u_lobe, vfloat *u_dir0,
                                vfloat *u_dir1, vfloat *u_roulette)
{
    vuint dim = 2u + SAMPLER_BOUNCE_DIMENSIONS * depth;
    vfloat unused;
    V_Uniform4Lanes(seed, pixel, s->index, 1u + 2u * depth, redraw, u_choice, u_point0,
                    u_point1, u_roulette);
    V_Uniform4Lanes(seed, pixel, s->index, 2u + 2u * depth, redraw, u_dir0, u_dir1, u_lobe,
                    &unused);
    *u_choice = V_Stratified1(s, st, dim, *u_choice);
    V_Stratified2(s, st, dim + 1u, u_point0, u_point1);
    *u_lobe = V_Stratified1(s, st, dim + 3u, *u_lobe);
    V_Stratified2(s, st, dim + 4u, u_dir0, u_dir1);
    *u_roulette = V_Stratified1(s, st, dim + 6u, *u_roulette);
}

#endif // CLRENDER_SAMPLER_LANES_H
