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

// Rows [lo, hi] of the tile starting at y0 whose pixel centres lie within mean_y +- extent_y
// (once per pair, not per pixel, so the builtin ceil and floor cost nothing that matters).
inline int2 rows_in_reach(float mean_y, float extent_y, int y0) {
    if (!ALPHA_CUT) return (int2)(0, TILE_SIZE - 1);
    float lo = ceil(mean_y - extent_y - (float)y0 - 0.5f), hi = floor(mean_y + extent_y - (float)y0 - 0.5f);
    return (int2)((int)CLAMPF(lo, 0.0f, (float)TILE_SIZE), (int)CLAMPF(hi, -1.0f, (float)(TILE_SIZE - 1)));
}

#endif
