// subgroups.h: the rasterizer backward's subgroup reduction (rasterize_backward.cl, -D SUBGROUP=32, a pixel per
// work-item): how a subgroup's lanes exchange values, by -D SUBGROUP_SOURCE (runtime.SUBGROUP_SOURCES):
//   SUBGROUP_PTX: NVIDIA's inline PTX (shfl.sync, vote.sync): its OpenCL has no subgroup functions;
//   SUBGROUP_KHR: cl_khr_subgroup_shuffle, in subgroups of a multiple of 32 (the xor masks stay within 32 lanes);
// and the butterfly that reduces a pair's sums over 32 lanes (subgroup_sums_8, subgroup_sums_16). With -D SUBGROUP=0
// (no subgroups) only SUBGROUP_SIZE_ATTRIBUTE, empty. SUBGROUP_SIZE_ATTRIBUTE: the kernel's required subgroup size.

#ifndef DC4GS_SUBGROUPS_H
#define DC4GS_SUBGROUPS_H

#include "common.h"

REQUIRE_DEFINED(SUBGROUP);

#if SUBGROUP
REQUIRE_DEFINED(SUBGROUP_SOURCE);   // one of SUBGROUP_KHR, SUBGROUP_PTX (runtime.SUBGROUP_SOURCES)
REQUIRE_DEFINED(SUBGROUP_KHR);
REQUIRE_DEFINED(SUBGROUP_PTX);
#if SUBGROUP != 32 || PIXELS_PER_ITEM != 1
#error "the subgroup reduction takes 32 lanes of one pixel each (the twin's tree)"
#endif
#endif

#if SUBGROUP && SUBGROUP_SOURCE == SUBGROUP_PTX
// NVIDIA's OpenCL has no subgroup functions; its inline PTX has the warp's (32 lanes, all active here).
inline float shuffle_xor(const float v, const int mask) {
    float out;
    asm volatile("shfl.sync.bfly.b32 %0, %1, %2, 0x1f, 0xffffffff;" : "=f"(out) : "f"(v), "r"(mask));
    return out;
}
inline int subgroup_any(const int predicate) {
    int out;
    asm volatile("{\n\t.reg .pred p_in, p_any;\n\tsetp.ne.s32 p_in, %1, 0;\n\t"
                 "vote.sync.any.pred p_any, p_in, 0xffffffff;\n\tselp.s32 %0, 1, 0, p_any;\n\t}"
                 : "=r"(out) : "r"(predicate));
    return out;
}
#define SUBGROUP_SIZE_ATTRIBUTE
#elif SUBGROUP && SUBGROUP_SOURCE == SUBGROUP_KHR
#pragma OPENCL EXTENSION cl_khr_subgroups : enable
#pragma OPENCL EXTENSION cl_khr_subgroup_shuffle : enable
#define shuffle_xor(v, mask) sub_group_shuffle_xor((v), (uint)(mask))
#define subgroup_any(predicate) sub_group_any(predicate)
#ifdef cl_intel_required_subgroup_size
#define SUBGROUP_SIZE_ATTRIBUTE __attribute__((intel_reqd_sub_group_size(SUBGROUP)))
#else
#define SUBGROUP_SIZE_ATTRIBUTE   // the device's own size: a multiple of SUBGROUP (the host checks)
#endif
#elif SUBGROUP
#error "SUBGROUP_SOURCE must be SUBGROUP_KHR or SUBGROUP_PTX"
#else
#define SUBGROUP_SIZE_ATTRIBUTE
#endif

#if SUBGROUP
#define SUBGROUP_MASK_BITS 5
// A pair's sums acc[0 .. used - 1] (used <= PAD, a power of two <= SUBGROUP) over the subgroup's lanes into
// part[0 .. used - 1], each sum by the butterfly's tree (xor masks 16 .. 1), in PAD - 1 + log2(SUBGROUP / PAD)
// shuffles (31 for 32 sums), not 5 per sum: at each step a lane keeps half of its values (the upper half where its
// lane bit is set), sends the other half to its partner and adds what it receives to what it keeps (the same two
// partial sums the plain butterfly adds); once it holds one value the remaining steps reduce that one. Lane l ends
// with sum `base`, which SUBGROUP / PAD lanes hold. One function per PAD, so that every loop has a literal trip
// count: a pad passed in left the compiler's unrolling to after inlining, too late (values held in memory).
#define DEFINE_SUBGROUP_SUMS(name, PAD)                                                                     \
    ALWAYS_INLINE void name(const float *acc, const int used, const int lane, __local float *part) {         \
        float v[PAD];                                                                                      \
        _Pragma("unroll") for (int k = 0; k < PAD; ++k) v[k] = k < used ? acc[k] : 0.f;                    \
        int base = 0;                                                                                      \
        _Pragma("unroll") for (int step = 0; step < SUBGROUP_MASK_BITS; ++step) {                          \
            const int mask = (SUBGROUP / 2) >> step, kept = (PAD >> step) / 2;                             \
            if (kept >= 1) {                                                                               \
                const int upper = (lane & mask) != 0;                                                      \
                _Pragma("unroll") for (int i = 0; i < kept; ++i) {                                         \
                    const float lo = v[i], hi = v[i + kept];                                               \
                    const float keep = upper ? hi : lo, send = upper ? lo : hi;                            \
                    v[i] = keep + shuffle_xor(send, mask);                                                 \
                }                                                                                          \
                base += upper ? kept : 0;                                                                  \
            } else {                                                                                       \
                v[0] += shuffle_xor(v[0], mask);                                                           \
            }                                                                                              \
        }                                                                                                  \
        if (lane % (SUBGROUP / PAD) == 0 && base < used) part[base] = v[0];                                \
    }
DEFINE_SUBGROUP_SUMS(subgroup_sums_8, 8)     // a crossing candidate's SPLIT_WIDTH split sums
DEFINE_SUBGROUP_SUMS(subgroup_sums_16, 16)   // the sums a pair's walk adds in place (rasterize_backward.cl LANE_SUMS)
#endif

#endif
