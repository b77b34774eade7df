// tiles.h: which tiles a projected Gaussian covers, shared by the projection (tile counts), the pair
// emission (isect.cl) and the rasterizer, so that all of them always agree.
// -D ALPHA_CUT (RenderOptions): cut a Gaussian's tiles to where its alpha can reach ALPHA_MIN (exact).

#ifndef DC4GS_TILES_H
#define DC4GS_TILES_H

#include "common.h"

REQUIRE_DEFINED(ALPHA_CUT);

// Tile rectangle [x0, x1) x [y0, y1) covered by the box mean +- half_size (px), clamped to the tile grid.
ALWAYS_INLINE int4 tile_rect(float2 mean, float2 half_size, int tiles_x, int tiles_y) {
    float inv = 1.0f / (float)TILE_SIZE;
    float x0 = CLAMPF((mean.x - half_size.x) * inv, 0.0f, (float)tiles_x);
    float y0 = CLAMPF((mean.y - half_size.y) * inv, 0.0f, (float)tiles_y);
    float x1 = CLAMPF((mean.x + half_size.x) * inv + 1.0f, 0.0f, (float)tiles_x);
    float y1 = CLAMPF((mean.y + half_size.y) * inv + 1.0f, 0.0f, (float)tiles_y);
    return (int4)((int)x0, (int)y0, (int)x1, (int)y1);   // values are >= 0: truncation is floor
}

inline int rect_area(int4 r) { return (r.z > r.x ? r.z - r.x : 0) * (r.w > r.y ? r.w - r.y : 0); }

// The tiles a Gaussian's pairs go to: its 3-sigma box (the reference rasterizers' rule) cut down to the
// box where alpha can reach ALPHA_MIN. Tiles outside the second box hold no pixel it could blend, so
// the image is exactly that of the 3-sigma rule, with fewer pairs to sort and walk.
ALWAYS_INLINE int4 pair_rect(float2 mean, float radius, float2 alpha_extent, int tiles_x, int tiles_y) {
#if ALPHA_CUT
    return tile_rect(mean, (float2)(MINF(radius, alpha_extent.x), MINF(radius, alpha_extent.y)), tiles_x, tiles_y);
#else
    return tile_rect(mean, (float2)(radius, radius), tiles_x, tiles_y);
#endif
}

#endif
