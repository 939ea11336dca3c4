// Vector lanes for kernels that run SIMD_WIDTH paths (or other items) per work-item, one a lane
// of float16 (float8) vectors: the lane types, conversions, per-lane records and the helpers
// whose results equal vecmath.h's scalar functions lane by lane (kernels/trace_simd.cl, the
// research probe kernels/simd_paths_probe.cl).
//
// Build options: SIMD_WIDTH 16 (default) or 8. SIMD_PORTABLE: no x86 builtins (sqrt and the
// lane mask's bits by portable code), as a compiler without __AVX512F__ / __AVX__ gets anyway.
#ifndef CLRENDER_SIMD_LANES_H
#define CLRENDER_SIMD_LANES_H

#include "vecmath.h"

#ifndef SIMD_WIDTH
#define SIMD_WIDTH 16
#endif

#if SIMD_WIDTH == 16
typedef float16 vfloat;
typedef int16 vint;
typedef uint16 vuint;
typedef ulong16 vulong;
#elif SIMD_WIDTH == 8
typedef float8 vfloat;
typedef int8 vint;
typedef uint8 vuint;
typedef ulong8 vulong;
#else
#error "SIMD_WIDTH must be 8 or 16"
#endif

// Functions taking vectors are inlined, and keep their vectors whole (clang's
// min-legal-vector-width: without it LLVM may split 512-bit vectors into 256-bit halves on
// CPUs that prefer 256-bit vectors, Skylake-AVX512 and later among them).
// (a file may define SIMD_ATTR before including this one: the probe's experiment without it)
#ifndef SIMD_ATTR
#define SIMD_ATTR __attribute__((min_vector_width(SIMD_WIDTH * 32)))
#endif
#define SIMD_FN CL_INLINE SIMD_ATTR

// Per-lane records of a vector: written lane by lane (.s[j]), read whole (.v). A vector's lane
// written at a variable index would cost a store and a load of the whole vector.
#define LANES(type, vtype)                                                                     \
    union {                                                                                    \
        vtype v;                                                                               \
        type s[SIMD_WIDTH];                                                                    \
    }

#define AS_VFLOAT(x) __builtin_astype((x), vfloat)
#define AS_VUINT(x) __builtin_astype((x), vuint)
#define TO_VFLOAT(x) __builtin_convertvector((x), vfloat)
#define TO_VINT(x) __builtin_convertvector((x), vint)
#define TO_VUINT(x) __builtin_convertvector((x), vuint)
#define TO_VULONG(x) __builtin_convertvector((x), vulong)

// Lane j's bits of a lane mask (V_Bits), lowest first.
#define FOR_EACH_LANE(j, bits)                                                                 \
    for (uint lanes_left_ = (bits), j = 0u;                                                    \
         lanes_left_ != 0u && ((j = (uint)Ctz(lanes_left_)), 1); lanes_left_ &= lanes_left_ - 1u)

// ----------------------------------------------------------------------------- lane helpers

// Correctly rounded square root of every lane (PoCL does not inline sqrt(float16) on pip's
// PoCL 3.0: see vecmath.h; the x86 builtins are the same instruction, inlined).
SIMD_FN vfloat V_Sqrt(vfloat x)
{
#if defined(__AVX512F__) && SIMD_WIDTH == 16 && !defined(SIMD_PORTABLE)
    return __builtin_ia32_sqrtps512(x, 4); // 4: the current rounding mode
#elif defined(__AVX__) && SIMD_WIDTH == 8 && !defined(SIMD_PORTABLE)
    return __builtin_ia32_sqrtps256(x);
#else
    return sqrt(x);
#endif
}

// Bit j set where lane j of the mask is set (-1).
SIMD_FN uint V_Bits(vint mask)
{
#if defined(__AVX__) && SIMD_WIDTH == 16 && !defined(SIMD_PORTABLE)
    return (uint)__builtin_ia32_movmskps256(as_float8(mask.lo)) |
           ((uint)__builtin_ia32_movmskps256(as_float8(mask.hi)) << 8);
#elif defined(__AVX__) && SIMD_WIDTH == 8 && !defined(SIMD_PORTABLE)
    return (uint)__builtin_ia32_movmskps256(as_float8(mask));
#else
    uint bits = 0u;
    for (int j = 0; j < SIMD_WIDTH; ++j)
        bits |= ((uint)mask[j] & 1u) << j;
    return bits;
#endif
}

SIMD_FN vfloat V_Fabs(vfloat x)
{
    return AS_VFLOAT(AS_VUINT(x) & 0x7fffffffu);
}

// Copysign(x, y)
SIMD_FN vfloat V_Copysign(vfloat x, vfloat y)
{
    return AS_VFLOAT((AS_VUINT(x) & 0x7fffffffu) | (AS_VUINT(y) & 0x80000000u));
}

// Fmax/Fmin as vecmath.h (PoCL's): a NaN y gives x.
SIMD_FN vfloat V_Fmax(vfloat x, vfloat y)
{
    return ((y != y) | (x > y)) ? x : y;
}

SIMD_FN vfloat V_Fmin(vfloat x, vfloat y)
{
    return ((y != y) | (x < y)) ? x : y;
}

SIMD_FN vfloat V_MaxAbs3(vfloat x, vfloat y, vfloat z)
{
    return V_Fmax(V_Fabs(x), V_Fmax(V_Fabs(y), V_Fabs(z)));
}

// Dot3: (ax bx + ay by) + az bz, the products rounded apart.
SIMD_FN vfloat V_Dot3(vfloat ax, vfloat ay, vfloat az, vfloat bx, vfloat by, vfloat bz)
{
    vfloat px = ax * bx;
    vfloat py = ay * by;
    vfloat pz = az * bz;
    return (px + py) + pz;
}

// SinCos2Pi of vecmath.h on lanes; rint(v) for v in [0, 4] as (v + 2^23) - 2^23 (exact, ties
// to even as rint).
SIMD_FN vfloat V_SinCos2Pi(vfloat u, vfloat *cos_out)
{
    vfloat v = 4.0f * u;
    vfloat k = (v + 0x1p23f) - 0x1p23f;
    vint quadrant = TO_VINT(k) & 3;
    vfloat x = (v - k) * M_PI_2_F;
    vfloat z = x * x;
    vfloat s =
        x + x * z * (-1.6666654611e-1f + z * (8.3321608736e-3f + z * -1.9515295891e-4f));
    vfloat c = 1.0f - 0.5f * z +
               z * z * (4.1666645683e-2f + z * (-1.3887316255e-3f + z * 2.4433157118e-5f));
    vint odd = (quadrant & 1) != 0;
    vfloat sin_q = odd ? c : s;
    vfloat cos_q = odd ? s : c;
    *cos_out = ((quadrant == 1) | (quadrant == 2)) ? -cos_q : cos_q;
    return ((quadrant & 2) != 0) ? -sin_q : sin_q;
}

#endif // CLRENDER_SIMD_LANES_H
