// common.h: device code shared by every kernel file.
// Constants (TILE_SIZE, NEAR_PLANE, ALPHA_MIN, SH_C*, ...) arrive as -D options from dc4gs_cl/constants.py,
// record offsets (<PREFIX>_<FIELD>) from dc4gs_cl/layout.py, switches from the stage that builds the kernel.
//
// Hot code avoids builtin calls: in the PoCL builds we run on, builtins such as exp, sqrt, fmin, floor and
// even vload3 are opaque calls that stop the compiler from vectorising a loop across pixels or across
// work-items (7x slower measured in the rasterizer), so the helpers below are plain arithmetic and selects.

#ifndef DC4GS_COMMON_H
#define DC4GS_COMMON_H

// The structs passed by value (Camera, AdamStep), generated from dc4gs_cl/records.py.
#include "records.h"

// REQUIRE_DEFINED(X): X must come from the host as a -D option (the kernels keep no defaults: a missing
// one would otherwise read as 0 in #if and silently pick a variant). One line per option, at file scope.
#define REQUIRE_DEFINED(X) typedef char X##_must_come_from_the_host[(X) * 0 + 1]

// Inlined even where the compiler's cost model would not: constant arguments then specialise the body.
#define ALWAYS_INLINE inline __attribute__((always_inline))

// On a kernel whose work-item walks rows of its own (strided, a varying number): Intel's CPU compiler would pack
// work-items into vector lanes, each load then a gather, 2-10x slower than one work-item per thread (sum_pairs
// 9.8 -> 2.3 ms with DC4GS at 48k Gaussians, 1.9 s -> 0.2 s at a million; project_backward 9.3 -> 4.9 ms).
// Other compilers take no hint (PoCL's timings do not move with one).
#ifdef cl_intel_vec_len_hint
#define UNPACKED_WORK_ITEMS __attribute__((intel_vec_len_hint(1)))
#else
#define UNPACKED_WORK_ITEMS
#endif

// A frame whose pairs overflowed the capacity it was given, or whose Gaussians spanning runs the carry rows it was
// given (frame [FRAME_WORDS] uint, constants.py; FRAME_OVERFLOWED holds which: the bits PAIRS_OVERFLOWED and
// CARRY_OVERFLOWED): the kernels that change lasting state (parameters, Adam's moments, the window, the loss'
// sums) or read every pair of a Gaussian return at once, so that the iteration can run again as if it never had.
REQUIRE_DEFINED(PAIRS_OVERFLOWED);
REQUIRE_DEFINED(CARRY_OVERFLOWED);
#define FRAME_VOID(frame) ((frame)[FRAME_OVERFLOWED] != 0u)

#define MINF(a, b) ((a) < (b) ? (a) : (b))
#define MAXF(a, b) ((a) > (b) ? (a) : (b))
#define CLAMPF(x, lo, hi) MINF(MAXF((x), (lo)), (hi))
#define ABSF(x) ((x) < 0.0f ? -(x) : (x))

// exp(x) by range reduction: x = k ln2 + r with |r| <= ln2/2, exp(r) by a degree-5 minimax polynomial,
// 2^k through the exponent bits; x is clamped to [-87, 88]. Max relative error 1.8e-7 (float32 exp:
// 2.0e-7). k rounds to nearest with a plain conversion (no floor call).
inline float exp_poly(float x) {
    x = CLAMPF(x, -87.0f, 88.0f);
    float y = x * 1.4426950408889634f;
    int k = (int)(y + (y < 0.0f ? -0.5f : 0.5f));
    float kf = (float)k;
    float r = x - kf * 0.693145751953125f - kf * 1.428606765330187e-06f;
    float p = 1.0f + r * (0.9999997019767761f + r * (0.4999915063381195f + r * (0.1666763573884964f
              + r * (0.04189793020486832f + r * 0.008290314115583897f))));
    return p * as_float((k + 127) << 23);
}

// 1/sqrt(x) for x > 0 without a builtin call (so a pixel loop using it still vectorises): the classic
// bit-level first guess and three Newton steps; max relative error 1.5e-7 over [1e-30, 1e30].
// The float and float4 versions share the seed and the steps (float4: lane by lane, the same operations).
#define RSQRT_SEED 0x5f3759df
#define RSQRT_NEWTON(y, x) (y = y * (1.5f - 0.5f * (x) * y * y), y = y * (1.5f - 0.5f * (x) * y * y), \
                            y * (1.5f - 0.5f * (x) * y * y))
inline float rsqrt_nocall(float x) {
    float y = as_float(RSQRT_SEED - (as_int(x) >> 1));
    return RSQRT_NEWTON(y, x);
}

inline float4 rsqrt4_nocall(float4 x) {
    float4 y = as_float4((int4)(RSQRT_SEED) - (as_int4(x) >> 1));
    return RSQRT_NEWTON(y, x);
}

inline float sqrt_nocall(float x) { return x > 0.f ? x * rsqrt_nocall(x) : 0.f; }

// log(x) for x > 0: x = m 2^e with m in [sqrt(1/2), sqrt(2)), log m = 2 atanh(s), s = (m - 1) / (m + 1),
// |s| <= 0.172, by its series to s^9 (truncation 5e-10). Relative error ~1e-7.
inline float log_nocall(float x) {
    int bits = as_int(x);
    int e = ((bits >> 23) & 0xff) - 127;
    float m = as_float((bits & 0x7fffff) | 0x3f800000);
    int big = m > 1.41421356f;
    m = big ? 0.5f * m : m;
    e += big;
    float s = (m - 1.0f) / (m + 1.0f), s2 = s * s;
    return (float)e * 0.6931471805599453f + 2.0f * s * (1.0f + s2 * (1.0f / 3 + s2 * (1.0f / 5 + s2 * (1.0f / 7 + s2 * (1.0f / 9)))));
}

// ceil(x) for 0 <= x < 2^31.
inline float ceil_nonnegative(float x) {
    float f = (float)(int)x;
    return f < x ? f + 1.0f : f;
}

#define IS_FINITE(x) ((x) - (x) == 0.0f)   // false for NaN and +-infinity
// Three floats at index i of a packed array (vload3 / vstore3 are calls under PoCL).
#define LOAD3(p, i) ((float3)((p)[3 * (i)], (p)[3 * (i) + 1], (p)[3 * (i) + 2]))
#define STORE3(v, p, i) ((p)[3 * (i)] = (v).x, (p)[3 * (i) + 1] = (v).y, (p)[3 * (i) + 2] = (v).z)
#define DOT3(a, b) ((a).x * (b).x + (a).y * (b).y + (a).z * (b).z)

// Emulated float atomic add (compare-and-swap on the bit pattern): OpenCL 1.2 has no float atomics.
// The first compare-and-swap guesses 0.0f rather than reading *addr: a plain read there races with other
// work-items' compare-and-swap under the memory model (Oclgrind reports it); a wrong guess costs one more
// compare-and-swap, which then holds the value seen.
inline void atomic_add_float(volatile __global float *addr, float v) {
    union { unsigned int u; float f; } old, upd;
    old.u = 0u;
    do {
        upd.f = old.f + v;
        unsigned int seen = atomic_cmpxchg((volatile __global unsigned int *)addr, old.u, upd.u);
        if (seen == old.u) break;
        old.u = seen;
    } while (1);
}

#endif
