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
//      xor masks 16, 8, 4, 2, 1 (pixel index bits 4..0); -D SUBGROUP_SOURCE says how the lanes exchange values
//      (subgroups.h: NVIDIA's inline PTX or cl_khr_subgroup_shuffle).
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
#include "split.h"
#include "split_walk.h"
#include "subgroups.h"

// (-D SUBGROUP: subgroups.h; SPLIT_CANDIDATES, SPLIT_SUMS_PER_BLOCK: split_walk.h)
REQUIRE_DEFINED(STATS);
REQUIRE_DEFINED(DC_STATS);
REQUIRE_DEFINED(PAIR_SUMS);
REQUIRE_DEFINED(PIXEL_MASK);
REQUIRE_DEFINED(PART_CHUNK);
REQUIRE_DEFINED(DEAL_TILES);

// The cooperative shapes' partial rows (l_part): one per owner, the OWNER_ITEMS work-items that share one (a
// subgroup, or one work-item); lane: an item's place among them. CHUNK: the pairs walked before the owners' rows are
// added, as many as the rows hold (PART_CHUNK); the CPU shape's one chunk is the batch.
#define OWNER_ITEMS (SUBGROUP ? SUBGROUP : 1)
#define PART_OWNERS (ITEMS_PER_TILE / OWNER_ITEMS)
#define CHUNK (ITEMS_PER_TILE > 1 ? PART_CHUNK : BATCH)

// Sums whose lanes the pixel walk adds to in place: all but the split sums, whose lanes (split_lanes, from
// SUM_SPLIT on) hold only the candidates crossing the pair's pixels (crossing_range). ROW_SUMS: the sums of a
// pair's row held compactly (the split sums of its crossing candidates alone).
#if SPLIT_CANDIDATES
#define LANE_SUMS SUM_SPLIT
#define ROW_SUMS(cross) (SUM_SPLIT + SPLIT_WIDTH * ((cross).y - (cross).x))
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
#define ROW_SUMS(cross) SUM_WIDTH
#endif
#if SUBGROUP && (LANE_SUMS > 16 || SPLIT_WIDTH > 8)
#error "the subgroup reduction takes at most 16 sums in place and 8 per split candidate (subgroup_sums_16, _8)"
#endif

// The parameters every pair's walk takes: the pair's Gaussian (mean, conic and opacity, colour; its pair index and
// reach in the tile: l_* in local memory); the work-item's place (its first pixel's tile row and column, the tile's
// corner, the NDC scale of g); its pixels (load_pixels), whose T and behind each walk updates (backward_pair).
#define PAIR_PARAMS const float2 m, const float4 co, const float3 c, const int idx, const int4 span
#define PAIR_ARGS m, co, c, idx, span
#define ITEM_PARAMS const int row0, const int col0, const int x0, const int y0, const float ndc_x, const float ndc_y
#define ITEM_ARGS row0, col0, x0, y0, ndc_x, ndc_y
#define PIXEL_PARAMS const float *px, const float *py, const float *dr, const float *dg, const float *db, \
                     const float *bg_term, const int *last, float *T, float *behind
#define PIXEL_ARGS px, py, dr, dg, db, bg_term, last, T, behind

// One pair: this work-item's pixels within the Gaussian's reach, walked back past the Gaussian; its terms
// summed per lane of a column block into lanes (every block of a row adds into the same COL_BLOCK lanes, so the
// pixel loop carries no dependency and vectorises; lanes per column instead cost twice the zeroing and summing per
// pair: DC4GS' backward 17% slower). n_split, a constant at each call, adds the split terms of that many
// candidates, at t_split[0 .. n_split - 1], into split_lanes (SPLIT_WIDTH per candidate): each call then compiles
// to its own vectorised loop (a run-time test or trip count inside the loop stops vectorisation: 6x slower). With
// subgroups (one pixel) it records the pixel's split inputs in `pixel` (PIXEL_RECORD) instead.
ALWAYS_INLINE void backward_pair(PAIR_PARAMS, ITEM_PARAMS, const float4 line, const float *t_split, const int n_split,
                                 PIXEL_PARAMS, float lanes[][COL_BLOCK], float split_lanes[][COL_BLOCK], float *pixel) {
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
        // (DC_STATS comes with STATS, split sums with DC_STATS: statistics.SumsLayout)
#if STATS
        float gx = gmx * ndc_x, gy = gmy * ndc_y;
        lanes[SUM_ABS][cc - c0] += ABSF(gx);
        lanes[SUM_ABS + 1][cc - c0] += ABSF(gy);
        lanes[SUM_PIXELS][cc - c0] += blend ? 1.f : 0.f;
#endif
#if DC_STATS
        float g2 = gx * gx + gy * gy;
        float inv = g2 > 0.f ? rsqrt_nocall(g2) : 0.f;   // pairs with g = 0 add nothing
        lanes[SUM_DC][cc - c0] += gx * inv;
        lanes[SUM_DC + 1][cc - c0] += gy * inv;
        lanes[SUM_DC + 2][cc - c0] += g2 > 0.f ? 1.f : 0.f;
#endif
#if SPLIT_CANDIDATES
        // The pixel's split inputs: t along the candidate line, whether g != 0, the split lanes' values.
        float t_q = (px[p] - line.x) * line.z + (py[p] - line.y) * line.w;
        float has_g = g2 > 0.f ? 1.f : 0.f;
        float ux = gx * inv, uy = gy * inv, ax = ABSF(gx), ay = ABSF(gy);
#endif
#if SPLIT_CANDIDATES && SUBGROUP
        // The item's one pixel, each candidate's terms reduced after the walk; the walk holds no split lanes.
        pixel[PIXEL_T] = t_q;
        pixel[PIXEL_HAS_G] = has_g;
        pixel[PIXEL_VALUE + SPLIT_UX] = ux; pixel[PIXEL_VALUE + SPLIT_UY] = uy;
        pixel[PIXEL_VALUE + SPLIT_COUNT] = 1.f;
        pixel[PIXEL_VALUE + SPLIT_ABS_X] = ax; pixel[PIXEL_VALUE + SPLIT_ABS_Y] = ay;
#elif SPLIT_CANDIDATES && SPLIT_SUMS_PER_BLOCK
        if (n_split) {
            sv[0][cc - c0] = t_q;
            sv[1 + SPLIT_UX][cc - c0] = has_g * ux; sv[1 + SPLIT_UY][cc - c0] = has_g * uy;
            sv[1 + SPLIT_COUNT][cc - c0] = has_g;
            sv[1 + SPLIT_ABS_X][cc - c0] = has_g * ax; sv[1 + SPLIT_ABS_Y][cc - c0] = has_g * ay;
        }
#elif SPLIT_CANDIDATES
        if (n_split) add_split_terms(split_lanes, cc - c0, t_split, n_split, t_q, has_g, ux, uy, ax, ay);
#endif
        T[p] = t;
        behind[p] += blend ? w * c_dot : 0.f;
    END_PIXELS_IN_BLOCK
#if SPLIT_CANDIDATES && SPLIT_SUMS_PER_BLOCK
    if (n_split) add_block_split_terms(split_lanes, sv, t_split, n_split);
#endif
    END_BLOCKS_IN_REACH
}

// The first `sums` sums' lanes, zeroed before a walk adds to them.
ALWAYS_INLINE void zero_lanes(float lanes[][COL_BLOCK], const int sums) {
    for (int k = 0; k < sums; ++k)
        for (int cc = 0; cc < COL_BLOCK; ++cc) lanes[k][cc] = 0.f;
}

// A pair's sums over this work-item's pixels into acc, without split sums.
ALWAYS_INLINE void pair_sums(PAIR_PARAMS, ITEM_PARAMS, PIXEL_PARAMS, float *acc) {
    float lanes[SUM_WIDTH][COL_BLOCK];
    zero_lanes(lanes, LANE_SUMS);
    const float no_split[1] = {0.f};
    backward_pair(PAIR_ARGS, ITEM_ARGS, (float4)(0.f), no_split, 0, PIXEL_ARGS, lanes, lanes, NULL);
    for (int k = 0; k < SUM_WIDTH; ++k) acc[k] = lane_total(lanes[k]);
}

#if SPLIT_CANDIDATES
// A pair's sums over this work-item's pixels into acc, with split sums (sg: its split-geometry row): its row,
// ROW_SUMS(cross) sums held compactly; returns the crossing range. Only the candidates whose line crosses the
// pixels walked take split terms (none where the view gave no line: then the row holds no split sums), in one walk
// per crossing count (see backward_pair). The full row: a candidate with every walked pixel on its left has the
// pair's totals as its left sums (the same terms in the same order; in the CPU shape the walk's contracted mul-adds
// may round the total's u terms one ulp apart), one with none zeros; its rows of partial sums: all crossing.
ALWAYS_INLINE int2 split_pair_sums(PAIR_PARAMS, ITEM_PARAMS, PIXEL_PARAMS, __local const float *sg, float *acc) {
    float lanes[SUM_WIDTH][COL_BLOCK];
    zero_lanes(lanes, LANE_SUMS);
    float tk[SPLIT_CANDIDATES];
    const float4 line = candidate_line(sg, tk);
    const int split_ok = HAS_SPLIT_LINE(sg);
    int2 cross = split_ok ? crossing_range(line, tk, span, x0, y0, row0, col0)
                          : (int2)(SPLIT_CANDIDATES, SPLIT_CANDIDATES);
    if (cross.y - cross.x > MAX_FEW_CROSSING) cross = (int2)(0, SPLIT_CANDIDATES);   // the walk over all
    const int n_cross = cross.y - cross.x;
    __private float (*split_lanes)[COL_BLOCK] = lanes + SUM_SPLIT;   // private, not generic (CL3.0)
    zero_lanes(split_lanes, SPLIT_WIDTH * n_cross);
#define WALK(n_split) \
    backward_pair(PAIR_ARGS, ITEM_ARGS, line, tk + cross.x, n_split, PIXEL_ARGS, lanes, split_lanes, NULL)
    if (n_cross == 0) WALK(0);
    else if (n_cross == 1) WALK(1);
    else if (MAX_FEW_CROSSING >= 2 && n_cross == 2) WALK(2);
    else WALK(SPLIT_CANDIDATES);
#undef WALK
    for (int k = 0; k < LANE_SUMS; ++k) acc[k] = lane_total(lanes[k]);
    if (!split_ok) return cross;
    SPLIT_TOTALS(total, acc);
    for (int k = 0; k < SPLIT_CANDIDATES; ++k)
        for (int v = 0; v < SPLIT_WIDTH; ++v)
            acc[SUM_SPLIT + SPLIT_WIDTH * k + v] = k < cross.x ? 0.f : total[v];
    for (int k = 0; k < n_cross; ++k)
        for (int v = 0; v < SPLIT_WIDTH; ++v)
            acc[SUM_SPLIT + SPLIT_WIDTH * (cross.x + k) + v] = lane_total(split_lanes[SPLIT_WIDTH * k + v]);
    return (int2)(0, SPLIT_CANDIDATES);
}
#endif

#if SUBGROUP && SPLIT_CANDIDATES
// With subgroups: a pair's walk of this lane's pixel with no split lanes (sums in place into acc, the pixel's split
// inputs recorded in `pixel`, zeros out of the pair's reach), and tk, the candidates' positions; returns the crossing
// range, the subgroup's (crossing_range).
ALWAYS_INLINE int2 subgroup_split_walk(PAIR_PARAMS, ITEM_PARAMS, PIXEL_PARAMS, __local const float *sg, float *acc,
                                       float *tk, float *pixel) {
    float lanes[SUM_WIDTH][COL_BLOCK];
    zero_lanes(lanes, LANE_SUMS);
    const float4 line = candidate_line(sg, tk);
    const int2 cross = HAS_SPLIT_LINE(sg) ? crossing_range(line, tk, span, x0, y0, row0, col0)
                                          : (int2)(SPLIT_CANDIDATES, SPLIT_CANDIDATES);
    for (int k = 0; k < PIXEL_RECORD; ++k) pixel[k] = 0.f;   // out of the pair's reach: no split term
    backward_pair(PAIR_ARGS, ITEM_ARGS, line, tk, 0, PIXEL_ARGS, lanes, lanes, pixel);
    for (int k = 0; k < SUM_SPLIT; ++k) acc[k] = lane_total(lanes[k]);
    return cross;
}

// Each crossing candidate's split sums over the subgroup into part (after the sums in place, compactly), from each
// lane's pixel record (the terms the twin's walk adds to zero lanes): 5 values held at a time, not 25 through the
// walk. The crossing range is the subgroup's, and a vote makes the candidates reduced the same across a wider
// hardware subgroup.
ALWAYS_INLINE void subgroup_split_sums(const float *pixel, const float *tk, const int2 cross, const int lane,
                                       __local float *part) {
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
}
#endif

#if SUBGROUP
// The subgroup's sums of a pair (this lane's pixel: row0, col0) into its owner's partial row `part`, each reduced
// over the 32 lanes by the butterfly (subgroup_sums_16, _8); a pair that none of their pixels took part in adds
// zeros. Returns the row's crossing range (split sums: its sums, ROW_SUMS, held compactly; else unused).
ALWAYS_INLINE int2 subgroup_pair_row(PAIR_PARAMS, ITEM_PARAMS, PIXEL_PARAMS, __local const float *l_split, const int j,
                                     const int lane, __local float *part) {
    // Whether this lane's pixel takes part in the pair (within its reach, not past its last contributor).
    const int touched = row0 >= span.z && row0 <= span.w && col0 >= span.x && col0 <= span.y && idx <= last[0];
    float acc[SUM_WIDTH];
#if SPLIT_CANDIDATES
    float tk[SPLIT_CANDIDATES], pixel[PIXEL_RECORD];
    const int2 cross = subgroup_split_walk(PAIR_ARGS, ITEM_ARGS, PIXEL_ARGS, l_split + j * GEO_WIDTH, acc, tk, pixel);
#else
    const int2 cross = (int2)(0);   // no split sums: no crossing range
    pair_sums(PAIR_ARGS, ITEM_ARGS, PIXEL_ARGS, acc);
#endif
    if (subgroup_any(touched)) {
        subgroup_sums_16(acc, LANE_SUMS, lane, part);
#if SPLIT_CANDIDATES
        subgroup_split_sums(pixel, tk, cross, lane, part);
#endif
    } else {
        for (int k = lane; k < ROW_SUMS(cross); k += SUBGROUP) part[k] = 0.f;
    }
    return cross;
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

// This work-item's pixels, PIXELS_PER_ITEM from tile pixel lid * PIXELS_PER_ITEM on, of the tile at (x0, y0): their
// centres (px, py), T after the tile's last pair (the forward's final_T; 1 outside the image), dL/dpixel colour (dr,
// dg, db), bg_term = T_final background . dL/dpixel, behind = 0 (the colour behind: sum over the Gaussians already
// visited, those behind, of w c . dL/dpixel, the only way it enters the gradient) and the last pair each blended
// (first - 1 outside the image or masked out: keep, -D PIXEL_MASK). Returns one past the last pair any of them blended.
ALWAYS_INLINE int load_pixels(const int lid, const int x0, const int y0, const int width, const int height,
                              const int first, const float4 background, __global const float *final_T,
                              __global const int *last_pair, __global const float *dL_dimage,
                              __global const uchar *keep, float *px, float *py, float *T, float *dr, float *dg,
                              float *db, float *bg_term, float *behind, int *last) {
    int my_end = first;
    for (int p = 0; p < PIXELS_PER_ITEM; ++p) {
        int q = lid * PIXELS_PER_ITEM + p;
        int x = x0 + q % TILE_SIZE, y = y0 + q / TILE_SIZE;
        int inside = x < width && y < height;
        int pix = inside ? y * width + x : 0;
        if (PIXEL_MASK) inside = inside && keep[pix];
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
    return my_end;
}

// The end of the tile's walk: one past the last pair any of its pixels blended (the items' largest my_end).
ALWAYS_INLINE int tile_end(const int my_end, const int first, const int lid, __local int *l_end) {
#if ITEMS_PER_TILE > 1
    if (lid == 0) *l_end = first;
    barrier(CLK_LOCAL_MEM_FENCE);
    atomic_max(l_end, my_end);
    barrier(CLK_LOCAL_MEM_FENCE);
    return *l_end;
#else
    return my_end;
#endif
}

// The run's pairs no pixel of the tile reached (end .. hi - 1) still own a slot (-D PAIR_SUMS=1): zeros.
ALWAYS_INLINE void zero_unreached_slots(const int end, const int lo, const int hi, const uint pair0, const int lid,
                                        __global float *sums) {
    const int unreached = max(end, lo);
    for (int k = lid; k < (hi - unreached) * SUM_WIDTH; k += ITEMS_PER_TILE)
        sums[(size_t)(unreached - pair0) * SUM_WIDTH + k] = 0.f;
}

// The batch of the tile's pairs base .. base + count - 1 into local memory: each pair's Gaussian, its values, its
// reach in the tile at (x0, y0) and, with split sums, its split-geometry row; between barriers (the last batch's
// pairs done, this one's loaded).
ALWAYS_INLINE void load_batch(const int base, const int count, const int lid, const int x0, const int y0,
                              __global const uint *gaussian_of_pair, __global const float *mean2d,
                              __global const float *conic_opacity, __global const float *rgb,
                              __global const float *alpha_extent, __global const float *split_geometry,
                              __local uint *l_gaussian, __local float2 *l_mean, __local float4 *l_conic_opacity,
                              __local float *l_rgb, __local int4 *l_reach, __local float *l_split) {
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
}

// A pair's row acc[0 .. used - 1] where its sums go: in the cooperative shapes (the twin) the owner's partial row
// `row` of l_part; with one work-item per tile the pair's slot (-D PAIR_SUMS=1, where the pair is in the run: idx <
// hi; a Gaussian with no split line leaves its split sums unwritten, as sum_pairs skips them) or, with float
// atomics, its Gaussian g's sums.
ALWAYS_INLINE void write_pair_row(const float *acc, const int used, const int idx, const int hi, const uint pair0,
                                  const uint g, __local float *l_part, const int row, __global float *sums) {
#if ITEMS_PER_TILE > 1
    for (int k = 0; k < used; ++k) l_part[row * SUM_WIDTH + k] = acc[k];
#elif PAIR_SUMS
    if (idx < hi)
        for (int k = 0; k < used; ++k) sums[(size_t)(idx - pair0) * SUM_WIDTH + k] = acc[k];
#else
    __global float *dst = sums + (size_t)g * SUM_WIDTH;
    for (int k = 0; k < used; ++k)
        if (acc[k] != 0.f) atomic_add_float(dst + k, acc[k]);
#endif
}

// Pair idx (entry j of the batch): its sums over this work-item's pixels into their place (write_pair_row, or with
// subgroups subgroup_pair_row; the owner's partial row `row` in the cooperative shapes, with split sums its crossing
// range beside it in l_cross). Null pointers for the local arrays a variant has none of.
ALWAYS_INLINE void pair_row(PAIR_PARAMS, ITEM_PARAMS, PIXEL_PARAMS, __local const float *l_split, const int j,
                            const int row, const int lane, __local float *l_part, __local uchar2 *l_cross,
                            const int hi, const uint pair0, const uint g, __global float *sums) {
#if SUBGROUP
    const int2 cross = subgroup_pair_row(PAIR_ARGS, ITEM_ARGS, PIXEL_ARGS, l_split, j, lane, l_part + row * SUM_WIDTH);
#else
    float acc[SUM_WIDTH];
#if SPLIT_CANDIDATES
    const int2 cross = split_pair_sums(PAIR_ARGS, ITEM_ARGS, PIXEL_ARGS, l_split + j * GEO_WIDTH, acc);
#else
    const int2 cross = (int2)(0);   // no split sums: no crossing range
    pair_sums(PAIR_ARGS, ITEM_ARGS, PIXEL_ARGS, acc);
#endif
    write_pair_row(acc, ROW_SUMS(cross), idx, hi, pair0, g, l_part, row, sums);
#endif
#if ITEMS_PER_TILE > 1 && SPLIT_CANDIDATES
    if (lane == 0) l_cross[row] = convert_uchar2(cross);
#endif
}

// The cooperative shapes' chunk of pairs chunk_base .. chunk_top - 1 of the batch at pair `base`: their owners'
// partial rows added in owner order, into the slots of the run's pairs (idx < hi), or with float atomics onto their
// Gaussians' sums; between barriers (the rows written, then read).
ALWAYS_INLINE void add_chunk_rows(const int chunk_base, const int chunk_top, const int base, const int hi,
                                  const uint pair0, const int lid, __local const float *l_part,
                                  __local const uchar2 *l_cross, __local const uint *l_gaussian,
                                  __global float *sums) {
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
    const int row0 = (lid * PIXELS_PER_ITEM) / TILE_SIZE;            // first tile row this item owns
    const int col0 = (lid * PIXELS_PER_ITEM) % TILE_SIZE;            // and first column (0 for whole rows)
    const int owner = lid / OWNER_ITEMS, lane = lid % OWNER_ITEMS;   // its partial rows (cooperative shapes)

    // The batch (load_batch); in the cooperative shapes the chunk's partial rows (l_part: [owner][pair of the
    // chunk][sum]; l_cross, with split sums: each row's crossing range, its split sums kept compactly) and the
    // tile's walk end. Null pointers for what a variant has none of.
    __local float2 l_mean[BATCH];
    __local float4 l_conic_opacity[BATCH];
    __local float l_rgb[BATCH * 3];
    __local int4 l_reach[BATCH];
    __local uint l_gaussian[BATCH];
#if SPLIT_CANDIDATES
    __local float l_split[BATCH * GEO_WIDTH];
#else
    __local float *const l_split = 0;
#endif
#if ITEMS_PER_TILE > 1
    __local float l_part[PART_OWNERS * PART_CHUNK * SUM_WIDTH];
    __local int l_end[1];
#else
    __local float *const l_part = 0;
    __local int *const l_end = 0;
#endif
#if ITEMS_PER_TILE > 1 && SPLIT_CANDIDATES
    __local uchar2 l_cross[PART_OWNERS * PART_CHUNK];
#else
    __local uchar2 *const l_cross = 0;
#endif
#if !PIXEL_MASK
    __global const uchar *const keep = 0;   // every pixel kept
#endif

    float px[PIXELS_PER_ITEM], py[PIXELS_PER_ITEM], T[PIXELS_PER_ITEM], bg_term[PIXELS_PER_ITEM];
    float dr[PIXELS_PER_ITEM], dg[PIXELS_PER_ITEM], db[PIXELS_PER_ITEM], behind[PIXELS_PER_ITEM];
    int last[PIXELS_PER_ITEM];
    const int end = tile_end(load_pixels(lid, x0, y0, width, height, first, background, final_T, last_pair, dL_dimage,
                                         keep, px, py, T, dr, dg, db, bg_term, behind, last), first, lid, l_end);
    if (PAIR_SUMS) zero_unreached_slots(end, lo, hi, pair0, lid, sums);

    for (int top = end; top > lo; top -= BATCH) {
        const int base = max(lo, top - BATCH), count = top - base;
        load_batch(base, count, lid, x0, y0, gaussian_of_pair, mean2d, conic_opacity, rgb, alpha_extent,
                   split_geometry, l_gaussian, l_mean, l_conic_opacity, l_rgb, l_reach, l_split);
        // Pairs back to front, a chunk at a time; the CPU shape's one chunk from pair 0, a constant: its base computed
        // made Intel's CPU compiler compare the pair index with last[] in 64-bit lanes, the walk 60% slower.
        for (int chunk_top = count; chunk_top > 0; chunk_top -= CHUNK) {
            const int chunk_base = ITEMS_PER_TILE > 1 ? max(0, chunk_top - CHUNK) : 0;
            for (int j = chunk_top - 1; j >= chunk_base; --j)
                pair_row(l_mean[j], l_conic_opacity[j], LOAD3(l_rgb, j), base + j, l_reach[j], ITEM_ARGS, PIXEL_ARGS,
                         l_split, j, owner * PART_CHUNK + j - chunk_base, lane, l_part, l_cross, hi, pair0,
                         l_gaussian[j], sums);
            if (ITEMS_PER_TILE > 1)
                add_chunk_rows(chunk_base, chunk_top, base, hi, pair0, lid, l_part, l_cross, l_gaussian, sums);
        }
    }
}
