// rasterize_backward.cl: tile rasterizer, backward. One work-group per tile (the forward's shape, see
// raster.h), back to front from the last pair any of its pixels blended.
//   in  dL_dimage [H*W*3]; final_T [H*W], last_pair [H*W]: from the forward; the rest as in rasterize.cl
//       keep [H*W] uchar, -D PIXEL_MASK=1 only: 0 where the view is masked out; such a pixel is treated as
//       one outside the image: it adds no gradient and no statistic (the loss also ignores it, loss.cl)
//   out sums: per Gaussian, its terms summed over this view's pixels where it was blended (the SUM record:
//       offsets SUM_<FIELD> and SUM_WIDTH are -D options from dc4gs_cl/backward/rasterize_backward.py,
//       SumsLayout). Two designs (-D PAIR_SUMS):
//         0: sums [N*SUM_WIDTH], added to with float atomics (the host zeroes it first);
//         1: sums [(pair_end - pair0)*SUM_WIDTH], one slot per pair of this launch's tiles (pair p at slot
//            p - pair0), written in full (zeros for pairs past the walk) except the split sums of a Gaussian
//            with no split line, which sum_pairs skips; no atomics; sum_pairs (sum_pairs.cl) then adds each
//            Gaussian's slots in a fixed order: deterministic.
//       A launch walks the tiles tile0 .. tile0 + groups - 1; the host cuts a frame with many pairs into
//       such runs (dc4gs_cl/backward/rasterize_backward.py, tile_runs) so fewer slots are held at once.
//       The terms:
//         SUM_MEAN2D +0,1   dL/dmean2d, px
//         SUM_CONIC  +0,1,2 dL/d(a, b, c) of conic_opacity
//         SUM_OPACITY       dL/dopacity (after the sigmoid)
//         SUM_RGB    +0,1,2 dL/drgb
//       densification statistics, where enabled; g = pixel j's dL/dmean2d in NDC units (x 0.5 W, 0.5 H):
//         SUM_ABS    +0,1   sum |g_x|, |g_y|                      (-D STATS)
//         SUM_PIXELS        pixels where blended (Pixel-GS)         (-D STATS)
//         SUM_DC     +0,1,2 sum of g/|g| and the count, |g| > 0     (-D DC_STATS)
//         SUM_SPLIT  +5k+0..4 for split candidate k: the same five sums (u_x, u_y, count, |g_x|, |g_y|)
//                    over the pixels left of it (-D SPLIT_CANDIDATES = N > 0; split_geometry [N*GEO_WIDTH]
//                    from split_geometry.cl, the GEO record, says where the candidates fall); -D
//                    SPLIT_SUMS_PER_BLOCK=1 adds them per column block after its pixels (Tuning.split_sums_per_block)
// Per pair, each work-item sums its pixels' terms privately; the sums reach `sums` once per (tile,
// Gaussian) pair (-D ITEMS_PER_TILE > 1 first combines the items' partial sums in local memory).

#include "raster.h"

REQUIRE_DEFINED(STATS);
REQUIRE_DEFINED(DC_STATS);
REQUIRE_DEFINED(SPLIT_CANDIDATES);
REQUIRE_DEFINED(PAIR_SUMS);
REQUIRE_DEFINED(PIXEL_MASK);
REQUIRE_DEFINED(SPLIT_SUMS_PER_BLOCK);

// A column block's values as one vector (floatB), for the split sums' explicit vector adds.
#if COL_BLOCK == 8
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

// One pair: this work-item's pixels within the Gaussian's reach, walked back past the Gaussian; its terms
// summed per lane of a column block into lanes. with_split, a constant at each call, adds the split terms:
// each call then compiles to its own vectorised loop (a run-time test inside the loop stops vectorisation:
// 6x slower).
ALWAYS_INLINE void backward_pair(const float2 m, const float4 co, const float3 c, const int idx, const int4 span,
                                 const int row0, const int col0, const float ndc_x, const float ndc_y,
                                 const float4 line, const float *tk, const int with_split,
                                 const float *px, const float *py, const float *dr, const float *dg, const float *db,
                                 const float *bg_term, const int *last, float *T, float *behind,
                                 float lanes[][COL_BLOCK]) {
    FOR_BLOCKS_IN_REACH(span, row0, col0)
#if SPLIT_CANDIDATES && SPLIT_SUMS_PER_BLOCK
    float sv[6][COL_BLOCK];          // the block's pixels: t along the candidate line, then the five split terms
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
#if SPLIT_CANDIDATES
        if (with_split) {
        float t_q = (px[p] - line.x) * line.z + (py[p] - line.y) * line.w;
        float has_g = g2 > 0.f ? 1.f : 0.f;
        float ux = gx * inv, uy = gy * inv, ax = ABSF(gx), ay = ABSF(gy);
#if SPLIT_SUMS_PER_BLOCK
        sv[0][cc - c0] = t_q; sv[1][cc - c0] = has_g * ux; sv[2][cc - c0] = has_g * uy; sv[3][cc - c0] = has_g;
        sv[4][cc - c0] = has_g * ax; sv[5][cc - c0] = has_g * ay;
#else
        // Fully unrolled: a loop here keeps the compiler from vectorising the pixel loop (11x slower).
        #pragma unroll
        for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
            float left = t_q < tk[k] ? has_g : 0.f;
            lanes[SUM_SPLIT + 5 * k][cc - c0] += left * ux;
            lanes[SUM_SPLIT + 5 * k + 1][cc - c0] += left * uy;
            lanes[SUM_SPLIT + 5 * k + 2][cc - c0] += left;
            lanes[SUM_SPLIT + 5 * k + 3][cc - c0] += left * ax;
            lanes[SUM_SPLIT + 5 * k + 4][cc - c0] += left * ay;
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
    if (with_split) {      // the block's split terms, in explicit vector adds (Tuning.split_sums_per_block)
        const floatB t_q = LOADB(sv[0]), zero = (floatB)(0.f);
        #pragma unroll
        for (int k = 0; k < SPLIT_CANDIDATES; ++k) {
            #pragma unroll
            for (int v = 0; v < 5; ++v) {
                float *lane = lanes[SUM_SPLIT + 5 * k + v];
                STOREB(LOADB(lane) + (t_q < tk[k] ? LOADB(sv[1 + v]) : zero), lane);
            }
        }
    }
#endif
    END_BLOCKS_IN_REACH
}

// A sum's COL_BLOCK lanes added pairwise, halves at a time, in vector adds: added lane by lane, once per sum and
// pair, they cost 10-20% of DC4GS' backward on PoCL (bench_dc4gs, 48k Gaussians: 20.0 -> 18.0 ms).
ALWAYS_INLINE float lane_total(const float *lane) {
#if COL_BLOCK == 8
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

__kernel __attribute__((reqd_work_group_size(ITEMS_PER_TILE, 1, 1)))
void rasterize_backward(const int width, const int height, const int tiles_x, const int tile0, const uint pair0,
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
    const int tile = tile0 + (int)get_group_id(0), lid = get_local_id(0);
    const int x0 = (tile % tiles_x) * TILE_SIZE, y0 = (tile / tiles_x) * TILE_SIZE;
    const int first = ranges[2 * tile];
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
    __local float l_sums[BATCH * SUM_WIDTH];
    __local int l_end;
#endif

    const int row0 = (lid * PIXELS_PER_ITEM) / TILE_SIZE;            // first tile row this item owns
    const int col0 = (lid * PIXELS_PER_ITEM) % TILE_SIZE;            // and first column (0 for whole rows)
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
    // Pairs no pixel reached still own a slot: zero it.
    const int range_end = ranges[2 * tile + 1];
    for (int k = lid; k < (range_end - end) * SUM_WIDTH; k += ITEMS_PER_TILE)
        sums[(size_t)(end - pair0) * SUM_WIDTH + k] = 0.f;
#endif

    for (int top = end; top > first; top -= BATCH) {
        const int base = max(first, top - BATCH), count = top - base;
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
#if ITEMS_PER_TILE > 1
        for (int k = lid; k < count * SUM_WIDTH; k += ITEMS_PER_TILE) l_sums[k] = 0.f;
#endif
        barrier(CLK_LOCAL_MEM_FENCE);

        for (int j = count - 1; j >= 0; --j) {
            const float2 m = l_mean[j];
            const float4 co = l_conic_opacity[j];
            const float3 c = (float3)(l_rgb[3 * j], l_rgb[3 * j + 1], l_rgb[3 * j + 2]);
            const int idx = base + j;
            const int4 span = l_reach[j];
            // Per lane of a column block (every block of a row adds into the same COL_BLOCK lanes), so the pixel
            // loop carries no dependency and vectorises; lanes are summed once per pair below. (Lanes per
            // column instead cost twice the zeroing and summing per pair: DC4GS' backward 17% slower.)
            float lanes[SUM_WIDTH][COL_BLOCK];
            // This pair's candidate line (c0.x, c0.y, dir.x, dir.y): pixel q is left of candidate k when
            // t(q) = (q - c0) . dir < t_k (t_0 = 0); no split terms where the view gave no line (dir = 0).
            float tk[SPLIT_CANDIDATES > 0 ? SPLIT_CANDIDATES : 1];
            float4 line = (float4)(0.f);
#if SPLIT_CANDIDATES
            __local const float *sg = l_split + j * GEO_WIDTH;
            line = (float4)(sg[GEO_ORIGIN], sg[GEO_ORIGIN + 1], sg[GEO_DIR], sg[GEO_DIR + 1]);
            const int split_ok = HAS_SPLIT_LINE(sg);
            tk[0] = 0.f;
            for (int k = 1; k < SPLIT_CANDIDATES; ++k) tk[k] = sg[GEO_T + k - 1];
#endif
            // Sums this pair fills: the split ones only where the view gave the Gaussian a line.
#if SPLIT_CANDIDATES
            const int used = split_ok ? SUM_WIDTH : SUM_SPLIT;
#else
            const int used = SUM_WIDTH;
#endif
            for (int k = 0; k < used; ++k)
                for (int cc = 0; cc < COL_BLOCK; ++cc) lanes[k][cc] = 0.f;
#if SPLIT_CANDIDATES
            if (split_ok)
                backward_pair(m, co, c, idx, span, row0, col0, ndc_x, ndc_y, line, tk, 1, px, py, dr, dg, db,
                              bg_term, last, T, behind, lanes);
            else
#endif
                backward_pair(m, co, c, idx, span, row0, col0, ndc_x, ndc_y, line, tk, 0, px, py, dr, dg, db,
                              bg_term, last, T, behind, lanes);
            float acc[SUM_WIDTH];
            for (int k = 0; k < used; ++k) acc[k] = lane_total(lanes[k]);
#if ITEMS_PER_TILE > 1
            for (int k = 0; k < used; ++k)
                if (acc[k] != 0.f) local_add_float(&l_sums[j * SUM_WIDTH + k], acc[k]);
#elif PAIR_SUMS
            for (int k = 0; k < used; ++k) sums[(size_t)(base + j - pair0) * SUM_WIDTH + k] = acc[k];
#else
            __global float *dst = sums + (size_t)l_gaussian[j] * SUM_WIDTH;
            for (int k = 0; k < used; ++k)
                if (acc[k] != 0.f) atomic_add_float(dst + k, acc[k]);
#endif
        }
#if ITEMS_PER_TILE > 1
        barrier(CLK_LOCAL_MEM_FENCE);
        for (int k = lid; k < count * SUM_WIDTH; k += ITEMS_PER_TILE) {
            float v = l_sums[k];
#if PAIR_SUMS
            sums[(size_t)(base - pair0) * SUM_WIDTH + k] = v;
#else
            if (v != 0.f) atomic_add_float(sums + (size_t)l_gaussian[k / SUM_WIDTH] * SUM_WIDTH
                                           + k % SUM_WIDTH, v);
#endif
        }
#endif
    }
}
