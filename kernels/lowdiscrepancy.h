// Building blocks of the low-discrepancy samplers (sampler.h): Sobol dimensions 0 and 1, Owen
// scrambling by a nested hash, random permutations of [0, n) and the Morton index of a pixel.
//
// Only Sobol dimensions 0 and 1 are ever needed: the samplers are "padded" (pbrt-v4's
// PaddedSobolSampler and ZSobolSampler, Burley's JCGT 9(4) 2020 shuffled Sobol), so every
// dimension pair is the 2D Sobol (0, 2)-sequence under its own scramble and its own shuffle of
// the sample index. Values are 32-bit binary fractions: bit 31 is the first binary digit.
#ifndef CLRENDER_LOWDISCREPANCY_H
#define CLRENDER_LOWDISCREPANCY_H

// Bit 0 to bit 31 and back, by swapping halves, bytes, nibbles, pairs and bits (no builtin: pip
// PoCL cannot inline its builtins, see vecmath.h).
inline uint LD_ReverseBits(uint x)
{
    x = (x << 16) | (x >> 16);
    x = ((x & 0x00FF00FFu) << 8) | ((x >> 8) & 0x00FF00FFu);
    x = ((x & 0x0F0F0F0Fu) << 4) | ((x >> 4) & 0x0F0F0F0Fu);
    x = ((x & 0x33333333u) << 2) | ((x >> 2) & 0x33333333u);
    x = ((x & 0x55555555u) << 1) | ((x >> 1) & 0x55555555u);
    return x;
}

// Sobol dimension 0 is the van der Corput sequence: the index's bits mirrored into the fraction.
inline uint Sobol_Dimension0(uint index)
{
    return LD_ReverseBits(index);
}

// Sobol dimension 1 (primitive polynomial x + 1), bit-reversed: its generator matrix is Pascal's
// triangle mod 2, so binary digit j + 1 of the value is the xor of the index bits i with
// C(i, j) odd, that is with j's bits a subset of i's (Lucas). That superset xor is five
// butterfly steps, one per bit of the bit position, instead of a loop over the index bits.
inline uint Sobol_Dimension1Reversed(uint index)
{
    index ^= (index >> 1) & 0x55555555u;
    index ^= (index >> 2) & 0x33333333u;
    index ^= (index >> 4) & 0x0F0F0F0Fu;
    index ^= (index >> 8) & 0x00FF00FFu;
    index ^= (index >> 16) & 0x0000FFFFu;
    return index;
}

inline uint Sobol_Dimension1(uint index)
{
    return LD_ReverseBits(Sobol_Dimension1Reversed(index));
}

// A hash in which output bit j depends only on input bits 0..j (and the seed): an addition and
// xor-multiplies by even constants, both bijective and carrying only upward. On bit-reversed
// values it is a nested (Owen) permutation: each binary digit is flipped by a function of the
// digits before it. Constants from N. Vegdahl, "Building a better LK hash" (2021).
inline uint LD_NestedHash(uint x, uint seed)
{
    x += seed;
    x ^= x * 0x6c50b47cu;
    x ^= x * 0xb82f1e52u;
    x ^= x * 0xc7afe638u;
    x ^= x * 0x8d22f6e6u;
    return x;
}

// Owen scrambling of a 32-bit binary fraction (Burley's nested_uniform_scramble): keeps every
// (0, m, 2)-net a net, and makes each point uniform over [0, 1) for a uniform seed. Applied to a
// sample index, the same function is a nested shuffle: indices 0 .. 2^m - 1 go to one aligned
// block of 2^m indices, in a random order.
inline uint LD_OwenScramble(uint value, uint seed)
{
    return LD_ReverseBits(LD_NestedHash(LD_ReverseBits(value), seed));
}

// Element i of a pseudo-random permutation of [0, n), chosen by key: a bijection of the smallest
// power-of-two range holding n (xor, odd multiplies, xorshifts, all modulo that range), iterated
// until it lands below n (cycle walking ends: the cycle through i holds i itself), then rotated
// by `rotation` mod n. With a uniform rotation every i lands on every element with probability
// 1/n exactly, whatever the bijection's quality.
inline uint LD_PermutationElement(uint i, uint n, uint key, uint rotation)
{
    uint mask = n - 1u;
    mask |= mask >> 1;
    mask |= mask >> 2;
    mask |= mask >> 4;
    mask |= mask >> 8;
    mask |= mask >> 16;
    uint half_bits = 1u; // about half the range's bit count (any shift of 1 or more is bijective)
    for (uint m = mask; m > 1u; m >>= 2)
        ++half_bits;
    do {
        i = ((i ^ key) * 0x9E3779B1u) & mask;
        i ^= i >> half_bits;
        i = ((i + (key >> 16)) * (key | 1u)) & mask;
        i ^= i >> 1;
        i = (i * 0x85EBCA77u) & mask;
        i ^= i >> half_bits;
    } while (i >= n);
    i += rotation % n;
    return i >= n ? i - n : i;
}

// The Morton (Z-order) code of (x, y), x in the even bits: consecutive codes walk 2 x 2 quads,
// then quads of quads. Valid for x, y < 2^16.
inline uint LD_Morton2(uint x, uint y)
{
    uint2 v = (uint2)(x, y);
    v = (v | (v << 8)) & 0x00FF00FFu;
    v = (v | (v << 4)) & 0x0F0F0F0Fu;
    v = (v | (v << 2)) & 0x33333333u;
    v = (v | (v << 1)) & 0x55555555u;
    return v.x | (v.y << 1);
}

// The 24 permutations of the digits {0, 1, 2, 3}, in lexicographic order: the image of digit d
// under permutation p is (LD_DIGIT_PERMUTATIONS[p] >> 2d) & 3.
__constant uchar LD_DIGIT_PERMUTATIONS[24] = {
    0xe4, 0xb4, 0xd8, 0x78, 0x9c, 0x6c, 0xe1, 0xb1, 0xc9, 0x39, 0x8d, 0x2d,
    0xd2, 0x72, 0xc6, 0x36, 0x4e, 0x1e, 0x93, 0x63, 0x87, 0x27, 0x4b, 0x1b};

// Digit (0 .. 3) under the permutation a 32-bit hash picks (multiply-high: 24 h / 2^32).
inline uint LD_PermuteDigit4(uint hash, uint digit)
{
    uint which = (uint)(((ulong)hash * 24u) >> 32);
    return (LD_DIGIT_PERMUTATIONS[which] >> (2u * digit)) & 3u;
}

#endif
