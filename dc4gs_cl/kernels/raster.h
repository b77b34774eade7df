// raster.h: the tile shape shared by the rasterizer's forward and backward kernels.
// -D PIXELS_PER_ITEM: pixels one work-item owns: 1, 2, 4, 8, or whole rows (a multiple of TILE_SIZE
// dividing TILE_SIZE^2); the work-group has TILE_SIZE^2 / PIXELS_PER_ITEM items. -D BATCH: Gaussians
// loaded into local memory at a time.

#ifndef DC4GS_RASTER_H
#define DC4GS_RASTER_H

#include "common.h"

#define TILE_PIXELS (TILE_SIZE * TILE_SIZE)
#define ITEMS_PER_TILE (TILE_PIXELS / PIXELS_PER_ITEM)
#define ROWS_PER_ITEM (PIXELS_PER_ITEM >= TILE_SIZE ? PIXELS_PER_ITEM / TILE_SIZE : 1)
#define COLS_PER_ITEM (PIXELS_PER_ITEM >= TILE_SIZE ? TILE_SIZE : PIXELS_PER_ITEM)
// Columns go in blocks of COL_BLOCK (one CPU vector), each skipped when out of a Gaussian's reach.
#define COL_BLOCK (COLS_PER_ITEM < 8 ? COLS_PER_ITEM : 8)

// Within the tile at (x0, y0): columns [x, y] and rows [z, w] whose pixel centres lie within
// mean +- extent (once per pair, not per pixel, so the builtin ceil and floor cost nothing that matters).
inline int4 reach(float2 mean, float2 extent, int x0, int y0) {
    if (!ALPHA_CUT) return (int4)(0, TILE_SIZE - 1, 0, TILE_SIZE - 1);
    float2 origin = (float2)((float)x0 + 0.5f, (float)y0 + 0.5f);
    float2 lo = ceil(mean - extent - origin), hi = floor(mean + extent - origin);
    return (int4)((int)CLAMPF(lo.x, 0.0f, (float)TILE_SIZE), (int)CLAMPF(hi.x, -1.0f, (float)(TILE_SIZE - 1)),
                  (int)CLAMPF(lo.y, 0.0f, (float)TILE_SIZE), (int)CLAMPF(hi.y, -1.0f, (float)(TILE_SIZE - 1)));
}

#endif
