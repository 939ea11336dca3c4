// Math helpers every kernel may share: CL_INLINE, inline replacements for the OpenCL builtins
// the path tracer calls per ray (bit for bit equal), lane reductions of 8-wide vectors, and
// SinCos2Pi (a faster sincos(2 pi u), not bit-equal).
//
// Why replacements: pip's PoCL 3.0 builds its builtin library for another CPU target than the
// kernels it compiles (target-cpu "skylake-avx512" for the library, the host's "znver3" for
// kernels), so LLVM refuses to inline builtins ("conflicting attributes"): every dot, vload3,
// sqrt or fmax becomes a real call, and each call spills all live vector registers to the stack.
// The functions here mirror PoCL's own definitions (read from the LLVM IR it links): the same
// operations in the same order. Products are taken in a separate statement from the sums that
// use them, because OpenCL C contracts a * b + c into an fma only within one expression.
// Rare cases (zero, tiny or huge vectors in Length3/Normalize3) fall back to the builtin.
//
// Names: a replacement is named after the builtin it replaces, capitalised, with the vector
// width (Dot3 for dot on float3, Fmax, Load3 for vload3): the one exception to the kernels'
// Module_Function names (like LuxCore's Dot and Cross). The other helpers are Module_Function.
#ifndef CLRENDER_VECMATH_H
#define CLRENDER_VECMATH_H

// Device functions are always inlined: a call spills the vector registers.
#define CL_INLINE inline __attribute__((always_inline))

// Kernel attribute KERNEL_SCALAR_WORK_ITEMS: on Intel's CPU runtime (its platform define
// CLRENDER_SCALAR_WORK_ITEMS, clrender/runtime.py PLATFORM_DEFINES) intel_vec_len_hint(1), which
// keeps that compiler from packing work-items into vector lanes; nothing elsewhere. For kernels
// whose work-items loop and branch apart (the trace kernels, whose SIMD twin fills its own lanes;
// the Voronoi cells and sums): packed, they ran 2.7-11x slower there (README, Intel's CPU runtime).
#ifdef CLRENDER_SCALAR_WORK_ITEMS
#pragma OPENCL EXTENSION cl_intel_vec_len_hint : enable
#define KERNEL_SCALAR_WORK_ITEMS __attribute__((intel_vec_len_hint(1)))
#else
#define KERNEL_SCALAR_WORK_ITEMS
#endif

// 8 floats from a 4-byte aligned address (vload8 without the call).
typedef float Float8Unaligned __attribute__((ext_vector_type(8), aligned(4)));

CL_INLINE float8 Load8(__global const float *p)
{
    return *(__global const Float8Unaligned *)p;
}

CL_INLINE float3 Load3(__global const float *p)
{
    return (float3)(p[0], p[1], p[2]);
}

// sqrt, fabs, copysign, floor, rint and the count of trailing zero bits. On PoCL
// (CLRENDER_CLANG_BUILTINS, set by clrender/runtime.py build_options) the clang builtins, which
// become LLVM instructions that need no call; elsewhere the OpenCL C builtins: every OpenCL C
// compiler has those, not every one the clang builtins (Oclgrind has no code for the LLVM
// intrinsics they become: bench/oclgrind_check.py). The same bits either way, but sqrt where a
// device's OpenCL sqrt is not correctly rounded (OpenCL allows 3 ulp).
#ifdef CLRENDER_CLANG_BUILTINS
CL_INLINE float Sqrt(float x)
{
    return __builtin_sqrtf(x);
}

CL_INLINE float Fabs(float x)
{
    return __builtin_fabsf(x);
}

CL_INLINE float Copysign(float x, float y)
{
    return __builtin_copysignf(x, y);
}

CL_INLINE float Floor(float x)
{
    return __builtin_floorf(x);
}

CL_INLINE float Rint(float x)
{
    return __builtin_rintf(x);
}

// Index of the lowest set bit of x != 0.
CL_INLINE int Ctz(uint x)
{
    return __builtin_ctz(x);
}
#else
CL_INLINE float Sqrt(float x)
{
    return sqrt(x);
}

CL_INLINE float Fabs(float x)
{
    return fabs(x);
}

CL_INLINE float Copysign(float x, float y)
{
    return copysign(x, y);
}

CL_INLINE float Floor(float x)
{
    return floor(x);
}

CL_INLINE float Rint(float x)
{
    return rint(x);
}

// Index of the lowest set bit of x != 0 (OpenCL C 1.2 has clz, not ctz).
CL_INLINE int Ctz(uint x)
{
    return 31 - (int)clz(x & (0u - x));
}
#endif

// fmax/fmin as PoCL defines them: a NaN y gives x.
CL_INLINE float Fmax(float x, float y)
{
    return (y != y || x > y) ? x : y;
}

CL_INLINE float Fmin(float x, float y)
{
    return (y != y || x < y) ? x : y;
}

CL_INLINE float3 Fmax3(float3 v, float y)
{
    return (float3)(Fmax(v.x, y), Fmax(v.y, y), Fmax(v.z, y));
}

CL_INLINE float3 Sqrt3(float3 v)
{
    return (float3)(Sqrt(v.x), Sqrt(v.y), Sqrt(v.z));
}

// dot(a, b) = (ax bx + ay by) + az bz, without fma.
CL_INLINE float Dot3(float3 a, float3 b)
{
    float3 p = a * b;
    return (p.x + p.y) + p.z;
}

CL_INLINE float Length3(float3 v)
{
    float s = Dot3(v, v);
    if (s >= 0x1p-126f && s < INFINITY)
        return Sqrt(s);
    return length(v);
}

CL_INLINE float3 Normalize3(float3 v)
{
    float s = Dot3(v, v);
    if (s >= 0x1p-126f && s < INFINITY) {
        float inv = 1.0f / Sqrt(s);
        return v * inv;
    }
    return normalize(v);
}

// cross(a, b): each component a difference of two rounded products.
CL_INLINE float3 Cross3(float3 a, float3 b)
{
    float3 p = a.yzx * b.zxy;
    float3 q = a.zxy * b.yzx;
    return p - q;
}

// Whether any component is > 0.
CL_INLINE bool AnyPositive3(float3 v)
{
    return v.x > 0.0f || v.y > 0.0f || v.z > 0.0f;
}

// ----------------------------------------------------------------------------- lane reductions

// Smallest of the 8 lanes (no lane is NaN).
CL_INLINE float Lanes_Min(float8 v)
{
    float4 v4 = v.lo < v.hi ? v.lo : v.hi;
    float2 v2 = v4.lo < v4.hi ? v4.lo : v4.hi;
    return v2.x < v2.y ? v2.x : v2.y;
}

// ----------------------------------------------------------------------------- approximations

// sin(2 pi u), and cos(2 pi u) in *cos_out, for u in [0, 1] (azimuth sampling): u is reduced
// exactly to a quadrant and r in [-1/2, 1/2], then minimax polynomials (Cephes sinf/cosf) of
// x = r pi/2 in [-pi/4, pi/4]; error below 2e-7. Replaces sincos(2 pi u), whose general
// argument reduction was 13 % of the path tracer's time (PoCL's SLEEF sincos, never inlined).
CL_INLINE float SinCos2Pi(float u, float *cos_out)
{
    float v = 4.0f * u;
    float k = Rint(v);
    int quadrant = (int)k & 3;
    float x = (v - k) * M_PI_2_F;
    float z = x * x;
    float s = x + x * z * (-1.6666654611e-1f + z * (8.3321608736e-3f + z * -1.9515295891e-4f));
    float c = 1.0f - 0.5f * z +
              z * z * (4.1666645683e-2f + z * (-1.3887316255e-3f + z * 2.4433157118e-5f));
    float sin_q = (quadrant & 1) ? c : s;
    float cos_q = (quadrant & 1) ? s : c;
    *cos_out = (quadrant == 1 || quadrant == 2) ? -cos_q : cos_q;
    return (quadrant & 2) ? -sin_q : sin_q;
}

#endif
