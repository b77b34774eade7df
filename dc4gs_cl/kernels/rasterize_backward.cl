// rasterize_backward.cl: tile rasterizer, backward. One work-group per tile (the forward's shape, see
// raster.h), back to front from the last pair any of its pixels blended.
//   in  dL_dimage [H*W*3]; final_T [H*W], last_pair [H*W]: from the forward; the rest as in rasterize.cl
//       keep [H*W] uchar, -D PIXEL_MASK=1 only: 0 where the view is masked out; such a pixel is treated as
//       one outside the image: it adds no gradient and no statistic (the loss also ignores it, loss.cl)
//   out sums: per Gaussian, its terms summed over this view's pixels where it was blended (the SUM record:
//       offsets SUM_<FIELD> and SUM_WIDTH are -D options from dc4gs_cl/statistics.py, SumsLayout). Two designs
//       (-D PAIR_SUMS):
//         0: sums [N*SUM_WIDTH], added to with float atomics (the host zeroes it first);
//         1: sums [(pair_end - pair0)*SUM_WIDTH], one slot per pair of this launch's run (pair p at slot
//            p - pair0), written in full (zeros for pairs past the walk) except the split sums of a Gaussian
//            with no split line, which sum_pairs skips; no atomics; sum_pairs (sum_pairs.cl) then adds each
//            Gaussian's slots in a fixed order: deterministic.
//       A launch covers every tile and writes the slots of the pairs pair0 .. pair_end - 1 (a run: the host cuts
//       a frame with many pairs into runs of consecutive pairs so that fewer slots are held at once, with nothing
//       read back: dc4gs_cl/backward/rasterize_backward.py, pair_runs); a tile with none of them returns at once,
//       one holding the run's first pairs is walked down to them only, one holding its last from its own last
//       blended pair (those past the run walked, not written: they set T and the colour behind).
//       The terms:
//         SUM_MEAN2D +0,1   dL/dmean2d, px
//         SUM_CONIC  +0,1,2 dL/d(a, b, c) of conic_opacity
//         SUM_OPACITY       dL/dopacity (after the sigmoid)
//         SUM_RGB    +0,1,2 dL/drgb
//       densification statistics, where enabled; g = pixel j's dL/dmean2d in NDC units (x 0.5 W, 0.5 H):
//         SUM_ABS    +0,1   sum |g_x|, |g_y|                      (-D STATS)
//         SUM_PIXELS        pixels where blended (Pixel-GS)         (-D STATS)
//         SUM_DC     +0,1,2 sum of g/|g| and the count, |g| > 0     (-D DC_STATS)
//         SUM_SPLIT  +SPLIT_WIDTH k + SPLIT_<LANE> for split candidate k: the dc and abs sums (the lanes
//                    SPLIT_UX, SPLIT_UY, SPLIT_COUNT, SPLIT_ABS_X, SPLIT_ABS_Y: statistics.SPLIT_LANES) over the
//                    pixels left of it (-D SPLIT_CANDIDATES = N > 0; split_geometry [N*GEO_WIDTH]
//                    from split_geometry.cl, the GEO record, says where the candidates fall; a pair's walk tests
//                    only the candidates whose line crosses its pixels, crossing_range); -D
//                    SPLIT_SUMS_PER_BLOCK=1 adds them per column block after its pixels (Tuning.split_sums_per_block)
// Per pair, each work-item sums its pixels' terms privately; the sums reach `sums` once per (tile,
// Gaussian) pair. With several items per tile (-D ITEMS_PER_TILE > 1, the cooperative shapes), the pair's sums
// are combined in a fixed order whatever the schedule, with no float atomics (bit-reproducible):
//   -D SUBGROUP=32: the 32 items of a subgroup (one pixel each) reduce each sum by a butterfly over the lanes,
//      xor masks 16, 8, 4, 2, 1 (pixel index bits 4..0); -D SUBGROUP_SOURCE says how the lanes exchange values:
//      SUBGROUP_PTX (NVIDIA's inline PTX shfl.sync, vote.sync) or SUBGROUP_KHR (cl_khr_subgroup_shuffle, in
//      subgroups of a multiple of 32: the xor masks stay within 32 lanes).
//   -D SUBGROUP=0: each item sums its own pixels (its lanes: rows added in order, then a column block's lanes
//      pairwise by halves), which for 32 pixels per item in 16-column blocks is the same tree as the butterfly:
//      the portable twin, computing the subgroup path's bits.
//   Each subgroup (or item) writes its sums of PART_CHUNK pairs to its row of l_part; after the chunk the rows
//   are added in subgroup order (0, 1, ...) and the pair's slot written. With split sums a row holds only the
//   split sums of the candidates crossing its pixels (l_cross: the range, crossing_range, over the subgroup's
//   pixels, so that its lanes walk and reduce alike); the others are zeros or the row's totals (part_row_sum), filled
//   in as the rows are added. Multiply-adds are not contracted
//   (FP_CONTRACT OFF) in these shapes, so a pixel's terms round alike however the items are laid out.

#if PIXELS_PER_ITEM < TILE_SIZE * TILE_SIZE     // ITEMS_PER_TILE > 1 (raster.h), before any code
#pragma OPENCL FP_CONTRACT OFF
#endif

#include "raster.h"

REQUIRE_DEFINED(STATS);
REQUIRE_DEFINED(DC_STATS);
REQUIRE_DEFINED(SPLIT_CANDIDATES);
REQUIRE_DEFINED(PAIR_SUMS);
REQUIRE_DEFINED(PIXEL_MASK);
REQUIRE_DEFINED(SPLIT_SUMS_PER_BLOCK);
REQUIRE_DEFINED(SUBGROUP);
REQUIRE_DEFINED(PART_CHUNK);
REQUIRE_DEFINED(DEAL_TILES);

#if SUBGROUP
REQUIRE_DEFINED(SUBGROUP_SOURCE);   // one of SUBGROUP_KHR, SUBGROUP_PTX (runtime.SUBGROUP_SOURCES)
REQUIRE_DEFINED(SUBGROUP_KHR);
REQUIRE_DEFINED(SUBGROUP_PTX);
#if SUBGROUP != 32 || PIXELS_PER_ITEM != 1
#error "the subgroup reduction takes 32 lanes of one pixel each (the twin's tree)"
#endif
#define SUBGROUP_MASK_BITS 5
#if SUBGROUP_SOURCE == SUBGROUP_PTX
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
#elif SUBGROUP_SOURCE == SUBGROUP_KHR
#pragma OPENCL EXTENSION cl_khr_subgroups : enable
#pragma OPENCL EXTENSION cl_khr_subgroup_shuffle : enable
#define shuffle_xor(v, mask) sub_group_shuffle_xor((v), (uint)(mask))
#define subgroup_any(predicate) sub_group_any(predicate)
#ifdef cl_intel_required_subgroup_size
#define SUBGROUP_SIZE_ATTRIBUTE __attribute__((intel_reqd_sub_group_size(SUBGROUP)))
#else
#define SUBGROUP_SIZE_ATTRIBUTE   // the device's own size: a multiple of SUBGROUP (the host checks)
#endif
#else
#error "SUBGROUP_SOURCE must be SUBGROUP_KHR or SUBGROUP_PTX"
#endif
#define PART_OWNERS (ITEMS_PER_TILE / SUBGROUP)

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
DEFINE_SUBGROUP_SUMS(subgroup_sums_16, 16)   // the sums the walk adds in place (LANE_SUMS, below)

#else
#define SUBGROUP_SIZE_ATTRIBUTE
#define PART_OWNERS ITEMS_PER_TILE
#endif

// A column block's values as one vector (floatB), for the split sums' explicit vector adds.
#if COL_BLOCK == 16
typedef float16 floatB;
#define LOADB(a) vload16(0, a)
#define STOREB(v, a) vstore16(v, 0, a)
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

// Sums whose lanes the pixel walk adds to in place: all but the split sums, whose lanes (split_lanes, from
// SUM_SPLIT on) hold only the candidates crossing the pair's pixels (crossing_range).
#if SPLIT_CANDIDATES
#define LANE_SUMS SUM_SPLIT
// Crossing counts with a walk of their own (each a copy of the walk); more take the walk over all candidates.
// Up to 4 measured no faster than up to 2 on PoCL (the built-in scene, where 30% of the walked pixels have 3 or 4).
#define MAX_FEW_CROSSING (SPLIT_CANDIDATES < 2 ? SPLIT_CANDIDATES : 2)
// With subgroups (a pixel per item) the walk records its pixel instead (backward_pair's `pixel`): t along the
// candidate line, whether g != 0, then the values of the split lanes (u_x, u_y, 1, |g_x|, |g_y| in SPLIT_<LANE>
// order) that a candidate with the pixel on its left adds.
#define PIXEL_T 0
#define PIXEL_HAS_G 1
#define PIXEL_VALUE 2
#define PIXEL_RECORD (PIXEL_VALUE + SPLIT_WIDTH)
#else
#define LANE_SUMS SUM_WIDTH
#endif
#if SUBGROUP && (LANE_SUMS > 16 || SPLIT_WIDTH > 8)
#error "the subgroup reduction takes at most 16 sums in place and 8 per split candidate (subgroup_sums_16, _8)"
#endif

// One pair: this work-item's pixels within the Gaussian's reach, walked back past the Gaussian; its terms
// summed per lane of a column block into lanes. n_split, a constant at each call, adds the split terms of that
// many candidates, at t_split[0 .. n_split - 1], into split_lanes (SPLIT_WIDTH per candidate): each call then
// compiles to its own vectorised loop (a run-time test or trip count inside the loop stops vectorisation: 6x
// slower). With subgroups (one pixel) it records the pixel's split inputs in `pixel` (PIXEL_RECORD) instead.
ALWAYS_INLINE void backward_pair(const float2 m, const float4 co, const float3 c, const int idx, const int4 span,
                                 const int row0, const int col0, const float ndc_x, const float ndc_y,
                                 const float4 line, const float *t_split, const int n_split,
                                 const float *px, const float *py, const float *dr, const float *dg, const float *db,
                                 const float *bg_term, const int *last, float *T, float *behind,
                                 float lanes[][COL_BLOCK], float split_lanes[][COL_BLOCK], float *pixel) {
    FOR_BLOCKS_IN_REACH(span, row0, col0)
#if SPLIT_CANDIDATES && SPLIT_SUMS_PER_BLOCK
    float sv[1 + SPLIT_WIDTH][COL_BLOCK];   // the block's pixels: t along the candidate line, then the split lanes
#endif
    FOR_PIXELS_IN_BLOCK(m, co, px, py)
        float G = exp_nonpositive(power);
        float oG = co.w * G;
        float alpha = MINF(ALPHA_MAX, oG);
        int blend = (idx <= last[p]) & (power <= 0.f) & (alpha >= ALPHA_MIN);
        float one_minus = 1.f - alpha;
        float t = blend ? T[p] / one_minus : T[p];          // T before this Gaussian
        float w = alpha * t;
        // dC/dalpha = T c - (colour behind + T_final background) / (1 - alpha), dotted with dL/dC.
        float c_dot = c.x * dr[p] + c.y * dg[p] + c.z * db[p];
        float dL_dalpha = t * c_dot - (behind[p] + bg_term[p]) / one_minus;
        // alpha = min(ALPHA_MAX, o G): no gradient where the clamp holds.
        float dL_dG = (blend & (oG < ALPHA_MAX)) ? co.w * dL_dalpha : 0.f;
        float dL_do = (blend & (oG < ALPHA_MAX)) ? G * dL_dalpha : 0.f;
        float gG = dL_dG * G;
        float gmx = gG * (co.x * dx + co.y * dy), gmy = gG * (co.z * dy + co.y * dx);
        lanes[SUM_MEAN2D][cc - c0] += gmx;
        lanes[SUM_MEAN2D + 1][cc - c0] += gmy;
        lanes[SUM_CONIC][cc - c0] += -0.5f * gG * dx * dx;
        lanes[SUM_CONIC + 1][cc - c0] += -gG * dx * dy;
        lanes[SUM_CONIC + 2][cc - c0] += -0.5f * gG * dy * dy;
        lanes[SUM_OPACITY][cc - c0] += dL_do;
        float wb = blend ? w : 0.f;
        lanes[SUM_RGB][cc - c0] += wb * dr[p];
        lanes[SUM_RGB + 1][cc - c0] += wb * dg[p];
        lanes[SUM_RGB + 2][cc - c0] += wb * db[p];
#if STATS
        float gx = gmx * ndc_x, gy = gmy * ndc_y;
        lanes[SUM_ABS][cc - c0] += ABSF(gx);
        lanes[SUM_ABS + 1][cc - c0] += ABSF(gy);
        lanes[SUM_PIXELS][cc - c0] += blend ? 1.f : 0.f;
#if DC_STATS
        float g2 = gx * gx + gy * gy;
        float inv = g2 > 0.f ? rsqrt_nocall(g2) : 0.f;   // pairs with g = 0 add nothing
        lanes[SUM_DC][cc - c0] += gx * inv;
        lanes[SUM_DC + 1][cc - c0] += gy * inv;
        lanes[SUM_DC + 2][cc - c0] += g2 > 0.f ? 1.f : 0.f;
#if SPLIT_CANDIDATES && SUBGROUP
        // The item's one pixel: what its split terms are made of, each candidate's reduced after the walk
        // (PIXEL_RECORD); the walk holds no split lanes.
        pixel[PIXEL_T] = (px[p] - line.x) * line.z + (py[p] - line.y) * line.w;
        pixel[PIXEL_HAS_G] = g2 > 0.f ? 1.f : 0.f;
        pixel[PIXEL_VALUE + SPLIT_UX] = gx * inv; pixel[PIXEL_VALUE + SPLIT_UY] = gy * inv;
        pixel[PIXEL_VALUE + SPLIT_COUNT] = 1.f;
        pixel[PIXEL_VALUE + SPLIT_ABS_X] = ABSF(gx); pixel[PIXEL_VALUE + SPLIT_ABS_Y] = ABSF(gy);
#elif SPLIT_CANDIDATES
        if (n_split) {
        float t_q = (px[p] - line.x) * line.z + (py[p] - line.y) * line.w;
        float has_g = g2 > 0.f ? 1.f : 0.f;
        float ux = gx * inv, uy = gy * inv, ax = ABSF(gx), ay = ABSF(gy);
#if SPLIT_SUMS_PER_BLOCK
        sv[0][cc - c0] = t_q;
        sv[1 + SPLIT_UX][cc - c0] = has_g * ux; sv[1 + SPLIT_UY][cc - c0] = has_g * uy;
        sv[1 + SPLIT_COUNT][cc - c0] = has_g;
        sv[1 + SPLIT_ABS_X][cc - c0] = has_g * ax; sv[1 + SPLIT_ABS_Y][cc - c0] = has_g * ay;
#else
        // Fully unrolled: a loop here keeps the compiler from vectorising the pixel loop (11x slower).
        // A literal trip count, unrolled before the call is inlined; the candidates past n_split then fold away.
        #pragma unroll
        for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
            if (k >= n_split) break;
            float left = t_q < t_split[k] ? has_g : 0.f;
            split_lanes[SPLIT_WIDTH * k + SPLIT_UX][cc - c0] += left * ux;
            split_lanes[SPLIT_WIDTH * k + SPLIT_UY][cc - c0] += left * uy;
            split_lanes[SPLIT_WIDTH * k + SPLIT_COUNT][cc - c0] += left;
            split_lanes[SPLIT_WIDTH * k + SPLIT_ABS_X][cc - c0] += left * ax;
            split_lanes[SPLIT_WIDTH * k + SPLIT_ABS_Y][cc - c0] += left * ay;
        }
#endif
        }
#endif
#endif
#endif
        T[p] = t;
        behind[p] += blend ? w * c_dot : 0.f;
    END_PIXELS_IN_BLOCK
#if SPLIT_CANDIDATES && SPLIT_SUMS_PER_BLOCK
    if (n_split) {      // the block's split terms, in explicit vector adds (Tuning.split_sums_per_block)
        const floatB t_q = LOADB(sv[0]), zero = (floatB)(0.f);
        #pragma unroll
        for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
            if (k >= n_split) break;
            #pragma unroll
            for (int v = 0; v < SPLIT_WIDTH; ++v) {
                float *lane = split_lanes[SPLIT_WIDTH * k + v];
                STOREB(LOADB(lane) + (t_q < t_split[k] ? LOADB(sv[1 + v]) : zero), lane);
            }
        }
    }
#endif
    END_BLOCKS_IN_REACH
}

// A sum's COL_BLOCK lanes added pairwise, halves at a time, in vector adds: added lane by lane, once per sum and
// pair, they cost 10-20% of DC4GS' backward on PoCL (bench_dc4gs, 48k Gaussians: 20.0 -> 18.0 ms). Halves first
// (lane c with c + COL_BLOCK / 2): the butterfly's order (see the top).
ALWAYS_INLINE float lane_total(const float *lane) {
#if COL_BLOCK == 16
    const float16 w = vload16(0, lane);
    const float8 v = w.lo + w.hi;
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

#if SPLIT_CANDIDATES
// The rectangle of pixels a crossing range covers (item-relative rows and columns from its first, row0 and col0):
// with subgroups, the subgroup's (whole rows), so that its lanes walk alike and reduce the same candidates; else
// the work-item's pixels.
#if SUBGROUP
#define CROSS_ROWS (SUBGROUP / TILE_SIZE)
#define CROSS_COLS TILE_SIZE
#else
#define CROSS_ROWS ROWS_PER_ITEM
#define CROSS_COLS COLS_PER_ITEM
#endif

// The split candidates a pair's walk must test per pixel: (lo, hi), candidates lo .. hi - 1. t(q) rounds
// monotonically in each pixel coordinate, so over the pixels the walk visits in the rectangle at (row0, col0) (its
// rows within the span, its column blocks that meet the span) t lies within its values at the 4 corners: a
// candidate above them all has every walked pixel on its left (its left sums are the pair's totals), one at or
// below them none (zeros); only those in between, "crossing", are tested per pixel. A margin far above float
// rounding around t_k keeps pixels the walk might round across t_k tested: exact. The t_k increase with k (the
// candidates' order along the projected axis), so those with none left come first, those with all left last; were
// they out of order, every candidate counts as crossing. Large Gaussians span several tiles, each crossed by one
// or two candidates' lines. (Ternaries, not the integer min and max builtins, which PoCL calls rather than
// inlines: once per pair.)
ALWAYS_INLINE int2 crossing_range(const float4 line, const float *tk, const int4 span, const int x0, const int y0,
                                  const int row0, const int col0) {
    const int a = span.x - col0, b = span.y - col0;                   // the span, rectangle-relative
    const int r_lo = span.z > row0 ? span.z - row0 : 0;
    const int r_hi = span.w - row0 < CROSS_ROWS - 1 ? span.w - row0 : CROSS_ROWS - 1;
    if (b < 0 || a > CROSS_COLS - 1 || a > b || r_lo > r_hi)          // no pixel walked: none left of any
        return (int2)(SPLIT_CANDIDATES, SPLIT_CANDIDATES);
    const int c_lo = (a > 0 ? a : 0) / COL_BLOCK * COL_BLOCK;
    const int c_hi = (b < CROSS_COLS - 1 ? b : CROSS_COLS - 1) / COL_BLOCK * COL_BLOCK + COL_BLOCK - 1;
    float t_min = 0.f, t_max = 0.f, extent = 0.f;
    for (int corner = 0; corner < 4; ++corner) {
        // the pixel centres as the kernel sets px and py
        const float ex = ((float)(x0 + col0 + (corner & 1 ? c_hi : c_lo)) + 0.5f) - line.x;
        const float ey = ((float)(y0 + row0 + (corner & 2 ? r_hi : r_lo)) + 0.5f) - line.y;
        const float t = ex * line.z + ey * line.w;                    // as the walk computes t(q)
        t_min = corner ? MINF(t_min, t) : t;
        t_max = corner ? MAXF(t_max, t) : t;
        extent = MAXF(extent, ABSF(ex) + ABSF(ey));
    }
    const float margin = 1e-5f * (1.f + extent);
    int none_left = 0, all_left = 0, in_order = 1;
    for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
        const int none = t_min > tk[k] + margin, all = t_max < tk[k] - margin;
        in_order &= (!none | (none_left == k)) & (all | (all_left == 0));
        none_left += none;
        all_left += all;
    }
    return in_order ? (int2)(none_left, SPLIT_CANDIDATES - all_left) : (int2)(0, SPLIT_CANDIDATES);
}

// Sum k (< SUM_WIDTH) of a pair's row held compactly (row: its sums before SUM_SPLIT, then the split sums of the
// crossing candidates lo .. hi - 1 alone, crossing_range): a candidate below lo has none of the pixels on its left
// (zeros), one at or past hi all of them (the row's totals).
ALWAYS_INLINE float part_row_sum(__local const float *row, const int lo, const int hi, const int k) {
    if (k < SUM_SPLIT) return row[k];
    const int candidate = (k - SUM_SPLIT) / SPLIT_WIDTH, v = (k - SUM_SPLIT) % SPLIT_WIDTH;
    if (candidate < lo) return 0.f;
    if (candidate < hi) return row[SUM_SPLIT + SPLIT_WIDTH * (candidate - lo) + v];
    return row[SPLIT_TOTAL_AT(v)];
}

#endif

// The tile work-group `group` walks, of the tiles_x x tiles_y in the image (a launch holds a group per tile).
// -D DEAL_TILES (Tuning.deal_tiles, in a frame walked in runs; else 1: group g walks tile g, neighbours sharing
// Gaussians in the cache together): consecutive groups take tiles a stripe apart, the tiles cut into DEAL_TILES
// stripes of consecutive tiles (the first ones a tile longer where they do not divide evenly; group % DEAL_TILES
// picks the stripe, group / DEAL_TILES the tile in it), so that a run's consecutive tiles spread over the launch:
// CPU runtimes deal each core a chunk of consecutive groups (PoCL's pthread scheduler: hundreds at a time), which
// left a run's few hundred tiles to one core.
ALWAYS_INLINE int tile_of_group(const int group, const int tiles_x, const int tiles_y) {
    const int tiles = tiles_x * tiles_y, stripe = (tiles + DEAL_TILES - 1) / DEAL_TILES;   // the longer stripes'
    const int longer = tiles - DEAL_TILES * (stripe - 1);                                   // stripes that long
    const int s = group % DEAL_TILES, i = group / DEAL_TILES;
    return s * stripe - max(s - longer, 0) + i;
}

__kernel __attribute__((reqd_work_group_size(ITEMS_PER_TILE, 1, 1))) SUBGROUP_SIZE_ATTRIBUTE
void rasterize_backward(const int width, const int height, const int tiles_x, const uint pair0, const uint pair_end,
                        const float4 background,
                        __global const uint *ranges, __global const uint *gaussian_of_pair,
                        __global const float *mean2d, __global const float *conic_opacity, __global const float *rgb,
                        __global const float *alpha_extent, __global const float *final_T,
                        __global const int *last_pair, __global const float *dL_dimage,
                        __global const float *split_geometry,
#if PIXEL_MASK
                        __global const uchar *keep,
#endif
                        __global float *sums) {
    const int tile = tile_of_group(get_group_id(0), tiles_x, (height + TILE_SIZE - 1) / TILE_SIZE);
    const int lid = get_local_id(0);
    const int x0 = (tile % tiles_x) * TILE_SIZE, y0 = (tile / tiles_x) * TILE_SIZE;
    const int first = ranges[2 * tile], range_end = ranges[2 * tile + 1];
    if (range_end <= (int)pair0 || first >= (int)pair_end) return;     // none of the run's pairs: the whole group
    const int lo = max(first, (int)pair0), hi = min(range_end, (int)pair_end);   // the run's pairs in this tile
    const float ndc_x = 0.5f * (float)width, ndc_y = 0.5f * (float)height;

    __local float2 l_mean[BATCH];
    __local float4 l_conic_opacity[BATCH];
    __local float l_rgb[BATCH * 3];
    __local int4 l_reach[BATCH];
    __local uint l_gaussian[BATCH];
#if SPLIT_CANDIDATES
    __local float l_split[BATCH * GEO_WIDTH];
#endif
#if ITEMS_PER_TILE > 1
    __local float l_part[PART_OWNERS * PART_CHUNK * SUM_WIDTH];   // [owner][pair of the chunk][sum]
#if SPLIT_CANDIDATES
    __local uchar2 l_cross[PART_OWNERS * PART_CHUNK];   // each row's crossing range: its split sums kept compactly
#endif
    __local int l_end;
#if SUBGROUP
    const int owner = lid / SUBGROUP, lane = lid % SUBGROUP, owner_lane = lane;
#else
    const int owner = lid, owner_lane = 0;
#endif
#endif

    const int row0 = (lid * PIXELS_PER_ITEM) / TILE_SIZE;            // first tile row this item owns
    const int col0 = (lid * PIXELS_PER_ITEM) % TILE_SIZE;            // and first column (0 for whole rows)
#if SPLIT_CANDIDATES && SUBGROUP
    const int cross_row0 = lid / SUBGROUP * CROSS_ROWS, cross_col0 = 0;   // the subgroup's rows (crossing_range)
#elif SPLIT_CANDIDATES
    const int cross_row0 = row0, cross_col0 = col0;
#endif
    // Per pixel: T (after the Gaussian being visited), dL/dpixel colour (dr, dg, db), and
    // behind = sum over the Gaussians already visited (those behind) of w c . dL/dpixel, the only way the
    // colour behind enters the gradient; bg_term = T_final background . dL/dpixel.
    float px[PIXELS_PER_ITEM], py[PIXELS_PER_ITEM], T[PIXELS_PER_ITEM], bg_term[PIXELS_PER_ITEM];
    float dr[PIXELS_PER_ITEM], dg[PIXELS_PER_ITEM], db[PIXELS_PER_ITEM], behind[PIXELS_PER_ITEM];
    int last[PIXELS_PER_ITEM];
    int my_end = first;
    for (int p = 0; p < PIXELS_PER_ITEM; ++p) {
        int q = lid * PIXELS_PER_ITEM + p;
        int x = x0 + q % TILE_SIZE, y = y0 + q / TILE_SIZE;
        int inside = x < width && y < height;
        int pix = inside ? y * width + x : 0;
#if PIXEL_MASK
        inside = inside && keep[pix];
#endif
        px[p] = (float)x + 0.5f;
        py[p] = (float)y + 0.5f;
        T[p] = inside ? final_T[pix] : 1.f;
        dr[p] = inside ? dL_dimage[3 * pix] : 0.f;
        dg[p] = inside ? dL_dimage[3 * pix + 1] : 0.f;
        db[p] = inside ? dL_dimage[3 * pix + 2] : 0.f;
        bg_term[p] = T[p] * (background.x * dr[p] + background.y * dg[p] + background.z * db[p]);
        behind[p] = 0.f;
        last[p] = inside ? last_pair[pix] : first - 1;
        my_end = max(my_end, last[p] + 1);
    }
#if ITEMS_PER_TILE > 1
    if (lid == 0) l_end = first;
    barrier(CLK_LOCAL_MEM_FENCE);
    atomic_max(&l_end, my_end);
    barrier(CLK_LOCAL_MEM_FENCE);
    const int end = l_end;
#else
    const int end = my_end;
#endif
#if PAIR_SUMS
    // The run's pairs no pixel reached still own a slot: zero it.
    const int unreached = max(end, lo);
    for (int k = lid; k < (hi - unreached) * SUM_WIDTH; k += ITEMS_PER_TILE)
        sums[(size_t)(unreached - pair0) * SUM_WIDTH + k] = 0.f;
#endif

    for (int top = end; top > lo; top -= BATCH) {
        const int base = max(lo, top - BATCH), count = top - base;
        barrier(CLK_LOCAL_MEM_FENCE);
        for (int j = lid; j < count; j += ITEMS_PER_TILE) {
            uint g = gaussian_of_pair[base + j];
            l_gaussian[j] = g;
            l_mean[j] = vload2(g, mean2d);
            l_conic_opacity[j] = vload4(g, conic_opacity);
            l_rgb[3 * j] = rgb[3 * g]; l_rgb[3 * j + 1] = rgb[3 * g + 1]; l_rgb[3 * j + 2] = rgb[3 * g + 2];
            l_reach[j] = reach(l_mean[j], vload2(g, alpha_extent), x0, y0);
#if SPLIT_CANDIDATES
            for (int k = 0; k < GEO_WIDTH; ++k) l_split[j * GEO_WIDTH + k] = split_geometry[(size_t)g * GEO_WIDTH + k];
#endif
        }
        barrier(CLK_LOCAL_MEM_FENCE);

        // Pairs back to front, in the cooperative shapes in chunks of PART_CHUNK (their partial rows hold that
        // many); the CPU shape's one chunk is the batch.
#if ITEMS_PER_TILE > 1
        for (int chunk_top = count; chunk_top > 0; chunk_top -= PART_CHUNK) {
            const int chunk_base = max(0, chunk_top - PART_CHUNK);
#else
        {
            const int chunk_top = count, chunk_base = 0;
#endif
            for (int j = chunk_top - 1; j >= chunk_base; --j) {
                const float2 m = l_mean[j];
                const float4 co = l_conic_opacity[j];
                const float3 c = (float3)(l_rgb[3 * j], l_rgb[3 * j + 1], l_rgb[3 * j + 2]);
                const int idx = base + j;
                const int4 span = l_reach[j];
#if SUBGROUP
                // Whether this lane's pixel takes part in the pair (within its reach, not past its last contributor).
                const int touched = row0 >= span.z && row0 <= span.w && col0 >= span.x && col0 <= span.y
                                    && idx <= last[0];
#endif
                // Per lane of a column block (every block of a row adds into the same COL_BLOCK lanes), so the pixel
                // loop carries no dependency and vectorises; lanes are summed once per pair below. (Lanes per
                // column instead cost twice the zeroing and summing per pair: DC4GS' backward 17% slower.)
                float lanes[SUM_WIDTH][COL_BLOCK];
                for (int k = 0; k < LANE_SUMS; ++k)
                    for (int cc = 0; cc < COL_BLOCK; ++cc) lanes[k][cc] = 0.f;
                float acc[SUM_WIDTH];
#if SPLIT_CANDIDATES
                // This pair's candidate line (c0.x, c0.y, dir.x, dir.y): pixel q is left of candidate k when
                // t(q) = (q - c0) . dir < t_k (t_0 = 0); no split terms where the view gave no line (dir = 0).
                __local const float *sg = l_split + j * GEO_WIDTH;
                const float4 line = (float4)(sg[GEO_ORIGIN], sg[GEO_ORIGIN + 1], sg[GEO_DIR], sg[GEO_DIR + 1]);
                float tk[SPLIT_CANDIDATES];
                tk[0] = 0.f;
                for (int k = 1; k < SPLIT_CANDIDATES; ++k) tk[k] = sg[GEO_T + k - 1];
                // Only the candidates whose line crosses the pixels walked take split terms: lo .. hi - 1 (none where the
                // view gave no line).
                const int split_ok = HAS_SPLIT_LINE(sg);
                int2 cross = split_ok ? crossing_range(line, tk, span, x0, y0, cross_row0, cross_col0)
                                                : (int2)(SPLIT_CANDIDATES, SPLIT_CANDIDATES);
#if SUBGROUP
                // One walk, with no split lanes: the crossing candidates' terms come from the pixel after it.
                float pixel[PIXEL_RECORD];
                for (int k = 0; k < PIXEL_RECORD; ++k) pixel[k] = 0.f;   // out of the pair's reach: no split term
                backward_pair(m, co, c, idx, span, row0, col0, ndc_x, ndc_y, line, tk, 0, px, py, dr, dg, db, bg_term,
                              last, T, behind, lanes, lanes, pixel);
                for (int k = 0; k < SUM_SPLIT; ++k) acc[k] = lane_total(lanes[k]);
#else
                if (cross.y - cross.x > MAX_FEW_CROSSING) cross = (int2)(0, SPLIT_CANDIDATES);   // the walk over all
                const int n_cross = cross.y - cross.x;
                __private float (*split_lanes)[COL_BLOCK] = lanes + SUM_SPLIT;   // private, not generic (CL3.0)
                for (int k = 0; k < SPLIT_WIDTH * n_cross; ++k)
                    for (int cc = 0; cc < COL_BLOCK; ++cc) split_lanes[k][cc] = 0.f;
                // One call per crossing count, each its own vectorised loop (see backward_pair).
#define WALK(n_split) backward_pair(m, co, c, idx, span, row0, col0, ndc_x, ndc_y, line, tk + cross.x, n_split, \
                                    px, py, dr, dg, db, bg_term, last, T, behind, lanes, split_lanes, NULL)
                if (n_cross == 0) WALK(0);
                else if (n_cross == 1) WALK(1);
#if MAX_FEW_CROSSING >= 2
                else if (n_cross == 2) WALK(2);
#endif
                else WALK(SPLIT_CANDIDATES);
#undef WALK
                for (int k = 0; k < LANE_SUMS; ++k) acc[k] = lane_total(lanes[k]);
                // The full row: a candidate with every walked pixel on its left has the pair's totals as its left
                // sums (the same terms in the same order; in the CPU shape the walk's contracted mul-adds may round
                // the total's u terms one ulp apart), one with none zeros. (Its rows of partial sums: all crossing.)
                if (split_ok) {
                    SPLIT_TOTALS(total, acc);
                    for (int k = 0; k < SPLIT_CANDIDATES; ++k)
                        for (int v = 0; v < SPLIT_WIDTH; ++v)
                            acc[SUM_SPLIT + SPLIT_WIDTH * k + v] = k < cross.x ? 0.f : total[v];
                    for (int k = 0; k < n_cross; ++k)
                        for (int v = 0; v < SPLIT_WIDTH; ++v)
                            acc[SUM_SPLIT + SPLIT_WIDTH * (cross.x + k) + v] = lane_total(split_lanes[SPLIT_WIDTH * k + v]);
                    cross = (int2)(0, SPLIT_CANDIDATES);
                }
#endif
                const int used = SUM_SPLIT + SPLIT_WIDTH * (cross.y - cross.x);   // the row's sums, held compactly
#else
                const float no_split[1] = {0.f};
                backward_pair(m, co, c, idx, span, row0, col0, ndc_x, ndc_y, (float4)(0.f), no_split, 0, px, py, dr,
                              dg, db, bg_term, last, T, behind, lanes, lanes, NULL);
                for (int k = 0; k < SUM_WIDTH; ++k) acc[k] = lane_total(lanes[k]);
                const int used = SUM_WIDTH;
#endif
#if ITEMS_PER_TILE > 1
                // The pair's row, compact, into this owner's partial row (the chunk's end adds the owners' rows).
                __local float *part = l_part + (owner * PART_CHUNK + j - chunk_base) * SUM_WIDTH;
#if SPLIT_CANDIDATES
                if (owner_lane == 0) l_cross[owner * PART_CHUNK + j - chunk_base] = convert_uchar2(cross);
#endif
#if SUBGROUP
                // The subgroup's sums of the pair; a pair that none of its pixels took part in adds zeros.
                if (subgroup_any(touched)) {
#if SPLIT_CANDIDATES
                    subgroup_sums_16(acc, SUM_SPLIT, lane, part);
                    // Then each crossing candidate's split sums, from each lane's pixel (the terms the twin's walk
                    // adds to zero lanes): 5 values held at a time, not 25 through the walk. The crossing range is the
                    // subgroup's, and a vote makes the candidates reduced the same across a wider hardware subgroup.
                    #pragma unroll
                    for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
                        const int crossing = k >= cross.x && k < cross.y;
                        if (!subgroup_any(crossing)) continue;
                        const float left = pixel[PIXEL_T] < tk[k] ? pixel[PIXEL_HAS_G] : 0.f;
                        float terms[SPLIT_WIDTH];
                        for (int v = 0; v < SPLIT_WIDTH; ++v) terms[v] = 0.f + left * pixel[PIXEL_VALUE + v];
                        subgroup_sums_8(terms, crossing ? SPLIT_WIDTH : 0, lane,
                                        part + SUM_SPLIT + SPLIT_WIDTH * (crossing ? k - cross.x : 0));
                    }
#else
                    subgroup_sums_16(acc, SUM_WIDTH, lane, part);
#endif
                } else {
                    for (int k = lane; k < used; k += SUBGROUP) part[k] = 0.f;
                }
#else
                for (int k = 0; k < used; ++k) part[k] = acc[k];
#endif
#elif PAIR_SUMS
                // (a Gaussian with no split line: its split sums left unwritten, as sum_pairs skips them)
                if (idx < hi)
                    for (int k = 0; k < used; ++k) sums[(size_t)(idx - pair0) * SUM_WIDTH + k] = acc[k];
#else
                __global float *dst = sums + (size_t)l_gaussian[j] * SUM_WIDTH;
                for (int k = 0; k < used; ++k)
                    if (acc[k] != 0.f) atomic_add_float(dst + k, acc[k]);
#endif
            }
#if ITEMS_PER_TILE > 1
            // The chunk's sums: the owners' rows added in owner order, into the slots of the run's pairs.
            barrier(CLK_LOCAL_MEM_FENCE);
            const int in_run = min(chunk_top, hi - base) - chunk_base;
            for (int k = lid; k < in_run * SUM_WIDTH; k += ITEMS_PER_TILE) {
#if SPLIT_CANDIDATES
                const int pair = k / SUM_WIDTH, sum = k - pair * SUM_WIDTH;
                float v = 0.f;
                for (int o = 0; o < PART_OWNERS; ++o) {
                    const int row = o * PART_CHUNK + pair;
                    const int2 cross = convert_int2(l_cross[row]);
                    const float x = part_row_sum(l_part + row * SUM_WIDTH, cross.x, cross.y, sum);
                    v = o ? v + x : x;
                }
#else
                float v = l_part[k];
                for (int o = 1; o < PART_OWNERS; ++o) v += l_part[o * PART_CHUNK * SUM_WIDTH + k];
#endif
#if PAIR_SUMS
                sums[(size_t)(base + chunk_base - pair0) * SUM_WIDTH + k] = v;
#else
                if (v != 0.f) atomic_add_float(sums + (size_t)l_gaussian[chunk_base + k / SUM_WIDTH] * SUM_WIDTH
                                               + k % SUM_WIDTH, v);
#endif
            }
            barrier(CLK_LOCAL_MEM_FENCE);
#endif
        }
    }
}
