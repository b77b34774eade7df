// philox.h: counter-based random numbers (Philox4x32-10, Salmon et al. 2011, "Parallel random numbers: as easy
// as 1, 2, 3"), so that a work-item's draws depend on its counter and the key alone: the same on every device
// and in any launch order, and the same again when a run resumes (reference/mcmc.py computes them in NumPy).

#ifndef DC4GS_PHILOX_H
#define DC4GS_PHILOX_H

#include "common.h"

#define PHILOX_M0 0xD2511F53u
#define PHILOX_M1 0xCD9E8D57u
#define PHILOX_W0 0x9E3779B9u
#define PHILOX_W1 0xBB67AE85u

inline uint4 philox4x32_10(uint4 c, uint2 k) {
    for (int round = 0; round < 10; ++round) {
        uint hi0 = mul_hi(PHILOX_M0, c.x), lo0 = PHILOX_M0 * c.x;
        uint hi1 = mul_hi(PHILOX_M1, c.z), lo1 = PHILOX_M1 * c.z;
        c = (uint4)(hi1 ^ c.y ^ k.x, lo1, hi0 ^ c.w ^ k.y, lo0);
        k += (uint2)(PHILOX_W0, PHILOX_W1);
    }
    return c;
}

// A uniform in (0, 1] from the top 24 bits of a word (never 0: its log is finite).
inline float philox_uniform(uint word) { return (float)((word >> 8) + 1u) * (1.0f / 16777216.0f); }

// Four standard normals from one Philox draw, by Box-Muller on its words' two pairs.
inline float4 philox_normals(uint4 counter, uint2 key) {
    uint4 w = philox4x32_10(counter, key);
    float r0 = sqrt_nocall(-2.0f * log_nocall(philox_uniform(w.x))), t0 = 6.283185307179586f * philox_uniform(w.y);
    float r1 = sqrt_nocall(-2.0f * log_nocall(philox_uniform(w.z))), t1 = 6.283185307179586f * philox_uniform(w.w);
    return (float4)(r0 * cos(t0), r0 * sin(t0), r1 * cos(t1), r1 * sin(t1));
}

#endif
