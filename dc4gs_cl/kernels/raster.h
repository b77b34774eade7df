// raster.h: what the rasterizer's forward and backward kernels share: the tile shape, the Gaussian's
// value at a pixel, and the walk over the pixels within a Gaussian's reach in column blocks (with the backward's
// helpers for a column block's values: floatB, lane_total).
// -D PIXELS_PER_ITEM: pixels one work-item owns: 1, 2, 4, 8, or whole rows (a multiple of TILE_SIZE
// dividing TILE_SIZE^2); the work-group has TILE_SIZE^2 / PIXELS_PER_ITEM items. -D BATCH: Gaussians
// loaded into local memory at a time (both from render/tuning.py). -D FAST_EXP, ALPHA_CUT (RenderOptions).

#ifndef DC4GS_RASTER_H
#define DC4GS_RASTER_H

#include "tiles.h"

REQUIRE_DEFINED(FAST_EXP);

#define TILE_PIXELS (TILE_SIZE * TILE_SIZE)
#define ITEMS_PER_TILE (TILE_PIXELS / PIXELS_PER_ITEM)
#define ROWS_PER_ITEM (PIXELS_PER_ITEM >= TILE_SIZE ? PIXELS_PER_ITEM / TILE_SIZE : 1)
#define COLS_PER_ITEM (PIXELS_PER_ITEM >= TILE_SIZE ? TILE_SIZE : PIXELS_PER_ITEM)
// Columns go in blocks of COL_BLOCK (one CPU vector), each skipped when out of a Gaussian's reach; the backward's
// portable twin of the subgroup reduction takes whole 16-column rows (-D COL_BLOCK=16, rasterize_backward.cl).
#ifndef COL_BLOCK
#define COL_BLOCK (COLS_PER_ITEM < 8 ? COLS_PER_ITEM : 8)
#endif

// A column block's values as one vector (floatB), for the backward's explicit vector adds. 16 wide in two halves:
// PoCL 3.0 on a CPU with AVX-512 that its LLVM takes for one without (Zen 4 as znver3) passes a float16 to and from
// its built-in library by two ABIs, and vload16 returned garbage (every GPU-shape backward test failed there).
#if COL_BLOCK == 16
typedef float16 floatB;
#define LOADB(a) ((float16)(vload8(0, a), vload8(1, a)))
#define STOREB(v, a) do { const float16 v_ = (v); vstore8(v_.lo, 0, a); vstore8(v_.hi, 1, a); } while (0)
#elif COL_BLOCK == 8
typedef float8 floatB;
#define LOADB(a) vload8(0, a)
#define STOREB(v, a) vstore8(v, 0, a)
#elif COL_BLOCK == 4
typedef float4 floatB;
#define LOADB(a) vload4(0, a)
#define STOREB(v, a) vstore4(v, 0, a)
#elif COL_BLOCK == 2
typedef float2 floatB;
#define LOADB(a) vload2(0, a)
#define STOREB(v, a) vstore2(v, 0, a)
#else
typedef float floatB;
#define LOADB(a) ((a)[0])
#define STOREB(v, a) ((a)[0] = (v))
#endif

// A sum's COL_BLOCK lanes (the backward's per-column-block sums) added pairwise, halves at a time, in vector adds:
// added lane by lane, once per sum and pair, they cost 10-20% of DC4GS' backward on PoCL (bench_dc4gs, 48k
// Gaussians: 20.0 -> 18.0 ms). Halves first (lane c with c + COL_BLOCK / 2): the subgroup butterfly's order
// (rasterize_backward.cl, subgroups.h).
ALWAYS_INLINE float lane_total(const float *lane) {
#if COL_BLOCK == 16
    const float8 v = vload8(0, lane) + vload8(1, lane);   // the halves (not vload16: see LOADB)
    const float4 h = v.lo + v.hi;
#elif COL_BLOCK == 8
    const float8 v = vload8(0, lane);
    const float4 h = v.lo + v.hi;
#elif COL_BLOCK == 4
    const float4 h = vload4(0, lane);
#endif
#if COL_BLOCK >= 4
    const float2 q = h.lo + h.hi;
    return q.x + q.y;
#elif COL_BLOCK == 2
    return lane[0] + lane[1];
#else
    return lane[0];
#endif
}

// exp(x) for x <= 0: ours (FAST_EXP) or the driver's; below -87 it is exp(-87) ~ 1.6e-38, far under any
// alpha threshold.
inline float exp_nonpositive(float x) {
#if FAST_EXP
    return exp_poly(MINF(x, 0.0f));
#else
    return exp(MINF(x, 0.0f));
#endif
}

// The exponent of a Gaussian with conic (a, b, c) = co.xyz at offset (dx, dy) px from its mean.
ALWAYS_INLINE float gaussian_power(const float4 co, const float dx, const float dy) {
    return -0.5f * (co.x * dx * dx + co.z * dy * dy) - co.y * dx * dy;
}

// Within the tile at (x0, y0): columns [x, y] and rows [z, w] whose pixel centres lie within
// mean +- extent (once per pair, not per pixel, so the builtin ceil and floor cost nothing that matters).
inline int4 reach(float2 mean, float2 extent, int x0, int y0) {
    if (!ALPHA_CUT) return (int4)(0, TILE_SIZE - 1, 0, TILE_SIZE - 1);
    float2 origin = (float2)((float)x0 + 0.5f, (float)y0 + 0.5f);
    float2 lo = ceil(mean - extent - origin), hi = floor(mean + extent - origin);
    return (int4)((int)CLAMPF(lo.x, 0.0f, (float)TILE_SIZE), (int)CLAMPF(hi.x, -1.0f, (float)(TILE_SIZE - 1)),
                  (int)CLAMPF(lo.y, 0.0f, (float)TILE_SIZE), (int)CLAMPF(hi.y, -1.0f, (float)(TILE_SIZE - 1)));
}

// The walk over this work-item's pixels within a Gaussian's reach `span` (from reach()), written once for
// the forward and the backward: rows, and blocks of COL_BLOCK columns, outside the span are skipped.
// Between FOR_PIXELS_IN_REACH and END_PIXELS_IN_REACH: p is the pixel's index in the item's arrays, cc its
// column lane, dx, dy its offset from the mean m (px[p], py[p]: the pixel's centre), power the Gaussian's
// exponent there (conic co). The body may hold #if lines, which a macro argument could not.
#define FOR_BLOCKS_IN_REACH(span, row0, col0)                                                  \
    for (int rr = 0; rr < ROWS_PER_ITEM; ++rr) {                                                \
        if ((row0) + rr < (span).z || (row0) + rr > (span).w) continue;                         \
        for (int c0 = 0; c0 < COLS_PER_ITEM; c0 += COL_BLOCK) {                                 \
            if ((col0) + c0 + COL_BLOCK - 1 < (span).x || (col0) + c0 > (span).y) continue;
#define FOR_PIXELS_IN_BLOCK(m, co, px, py)                                                      \
            for (int cc = c0; cc < c0 + COL_BLOCK; ++cc) {                                      \
                const int p = rr * COLS_PER_ITEM + cc;                                          \
                const float dx = (px)[p] - (m).x, dy = (py)[p] - (m).y;                         \
                const float power = gaussian_power((co), dx, dy);
#define END_PIXELS_IN_BLOCK }
#define END_BLOCKS_IN_REACH } }
#define FOR_PIXELS_IN_REACH(m, co, span, row0, col0, px, py)                                   \
    FOR_BLOCKS_IN_REACH(span, row0, col0) FOR_PIXELS_IN_BLOCK(m, co, px, py)
#define END_PIXELS_IN_REACH END_PIXELS_IN_BLOCK END_BLOCKS_IN_REACH

#endif
