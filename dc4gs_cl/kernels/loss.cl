// loss.cl: training loss L = (1 - LAMBDA_DSSIM) L1 + LAMBDA_DSSIM (1 - SSIM) and its gradient dL/dx.
//
// Images x (rendered, not clamped) and y (target): [H][W][3] float32, row-major interleaved RGB,
// nominally in [0, 1]. A row is n3w = 3W floats and a pixel's same-channel neighbour is 3 floats away,
// so a 1D blur along a row (taps at +-3k floats) blurs the three channels at once. M = H * n3w floats.
// SSIM per channel: (2 SSIM_RADIUS + 1)-tap Gaussian SSIM_WEIGHTS (normalised, -D from dc4gs_cl/backward/loss.py), zero
// padding (outside pixels count 0 in every blurred moment), constants SSIM_C1, SSIM_C2.
//
// Two passes, each a vertical blur into local memory followed by a horizontal blur from it:
//   loss_ssim   x, y [H][n3w] -> d0, d1, d2 [H][n3w] float32 = dscale * (dS/dmu_x, dS/dE[x^2], dS/dE[xy]),
//               partial [H][groups per row][3]: each work-group's sums of |x - y|, (x - y)^2 and 1 - S
//   loss_grad   d0, d1, d2, x, y -> grad [H][n3w] float32, dL/dx = l1scale * sign(x - y) + blur(d0)
//               + 2 x blur(d1) + y blur(d2); its first work-group also does loss_reduce's work (one launch
//               fewer per training iteration: the partials are complete once loss_ssim has run)
//   loss_reduce partial -> stats [4] float32 += (loss, L1, 1 - SSIM, MSE) of this image (means over M),
//               for a loss without gradient (evaluation)
// A masked view (a mask, keep [H*W] uchar, 0 = masked out): mask_pixels zeroes x and y where masked, so
// masked pixels add no L1 and, in SSIM windows reaching them, are equal; M then counts the kept floats only
// (the scales are host arguments), and the backward skips masked pixels.
//   mask_pixels x [H*W*3], keep [H*W] -> out [H*W*3]: x where kept, else 0
// with S = AB / (CD), A = 2 mu_x mu_y + C1, B = 2 s_xy + C2, C = mu_x^2 + mu_y^2 + C1, D = s_xx + s_yy + C2,
// dscale = -LAMBDA_DSSIM / M, l1scale = (1 - LAMBDA_DSSIM) / M (the loss weights folded into the maps;
// the zero-padded blur is its own adjoint, so the gradient pass blurs the maps with the same window).
//
// Shape: a work-group of WG items (a power of two) owns WG * SEG consecutive floats of one row; item i
// owns floats [i SEG, (i + 1) SEG) of them. Local memory holds the vertical blurs of those floats plus
// PAD floats each side (zeros outside the row), so the horizontal taps need no bounds checks. The CPU
// shape (WG = 1, SEG = 2304) leaves straight inner loops over floats that the compiler vectorises 8 wide;
// `vectorize(enable)` lets it reorder the loops' float sums (no fast-math needed), `restrict` rules out
// aliasing between the buffers. GPUs use SEG = 1, WG = 256.

#include "common.h"

#define RADIUS SSIM_RADIUS
#define TAPS (2 * RADIUS + 1)
#define PAD (3 * RADIUS)             // floats either side of a group's span that its taps reach
#define SPAN (WG * SEG)              // floats of a row per work-group
#define LEN (SPAN + 2 * PAD)         // local floats per blurred map

#define GLOBAL_IN __global const float *restrict
#define GLOBAL_OUT __global float *restrict

__constant float WIN[TAPS] = {SSIM_WEIGHTS};

// Row offsets and weights of the vertical taps of row r; a row outside the image gets weight 0 and row
// r's offset, so every load stays in bounds with no per-float check.
#define VERTICAL_TAPS(off, w)                                       \
    int off[TAPS]; float w[TAPS];                                   \
    for (int k = 0; k < TAPS; ++k) {                                \
        int rr = r + k - RADIUS, inside = rr >= 0 && rr < h;        \
        w[k] = inside ? WIN[k] : 0.0f;                              \
        off[k] = (inside ? rr : r) * n3w;                           \
    }

// Local index ranges of the group's span: [jlo, jhi) lies in the row; [0, jlo) and [jhi, jend) outside it
// (zeros; the taps read no further than jend). Item lid takes every WG-th index of a range from its start + lid.
#define SPAN_RANGES                                                  \
    const int r = get_global_id(1), lid = get_local_id(0);          \
    const int g0 = get_group_id(0) * SPAN;    /* row float at local index PAD */ \
    const int jlo = max(PAD - g0, 0), jhi = min(LEN, n3w - g0 + PAD), jend = min(LEN, jhi + PAD);

// Float range [e0, e1) of the row owned by this item (empty past the row's end).
#define ITEM_RANGE                                                   \
    const int e0 = g0 + lid * SEG, e1 = min(e0 + SEG, n3w);

// Sums s[0..2] over the work-group by a tree in local memory red[3 WG]; the result is valid in item 0.
inline void work_group_sum3(float s[3], __local float *red) {
#if WG > 1
    const int lid = get_local_id(0);
    for (int q = 0; q < 3; ++q) red[q * WG + lid] = s[q];
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int step = WG / 2; step > 0; step >>= 1) {
        if (lid < step)
            for (int q = 0; q < 3; ++q) red[q * WG + lid] += red[q * WG + lid + step];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    for (int q = 0; q < 3; ++q) s[q] = red[q * WG];
#endif
}

// Run by one whole work-group of WG items: compensated strided sums of the partials (there can be
// thousands), then a tree; adds this image's means to stats.
inline void add_image_stats(__global const uint *frame, const int groups, const float inv_m, GLOBAL_IN partial,
                            __global float *stats, __local float *red) {
    if (FRAME_VOID(frame)) return;   // every item: the sums stay as they were
    float s[3] = {0.0f, 0.0f, 0.0f}, lost[3] = {0.0f, 0.0f, 0.0f};
    for (int g = get_local_id(0); g < groups; g += WG)
        for (int q = 0; q < 3; ++q) {   // Kahan summation
            float v = partial[3 * g + q] - lost[q], t = s[q] + v;
            lost[q] = (t - s[q]) - v;
            s[q] = t;
        }
    work_group_sum3(s, red);
    if (get_local_id(0) != 0) return;
    float l1 = s[0] * inv_m, dssim = s[2] * inv_m;
    stats[0] += (1.0f - LAMBDA_DSSIM) * l1 + LAMBDA_DSSIM * dssim;
    stats[1] += l1;
    stats[2] += dssim;
    stats[3] += s[1] * inv_m;
}

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void loss_ssim(const int n3w, const int h, const float dscale, GLOBAL_IN x, GLOBAL_IN y,
               GLOBAL_OUT d0, GLOBAL_OUT d1, GLOBAL_OUT d2, GLOBAL_OUT partial) {
    __local float mx_[LEN], my_[LEN], mxx_[LEN], myy_[LEN], mxy_[LEN], red[3 * WG];
    SPAN_RANGES
    VERTICAL_TAPS(off, w)
    for (int j = lid; j < jlo; j += WG) mx_[j] = my_[j] = mxx_[j] = myy_[j] = mxy_[j] = 0.0f;
    for (int j = jhi + lid; j < jend; j += WG) mx_[j] = my_[j] = mxx_[j] = myy_[j] = mxy_[j] = 0.0f;
    #pragma clang loop vectorize(enable)
    for (int j = jlo + lid; j < jhi; j += WG) {
        const int e = g0 - PAD + j;
        float sx = 0.0f, sy = 0.0f, sxx = 0.0f, syy = 0.0f, sxy = 0.0f;
        #pragma unroll
        for (int k = 0; k < TAPS; ++k) {
            float xv = x[off[k] + e], yv = y[off[k] + e];
            float wx = w[k] * xv, wy = w[k] * yv;
            sx += wx; sy += wy; sxx += wx * xv; syy += wy * yv; sxy += wx * yv;
        }
        mx_[j] = sx; my_[j] = sy; mxx_[j] = sxx; myy_[j] = syy; mxy_[j] = sxy;
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    ITEM_RANGE
    float s_abs = 0.0f, s_sq = 0.0f, s_dssim = 0.0f;
    #pragma clang loop vectorize(enable)
    for (int e = e0; e < e1; ++e) {
        const int j = e - g0 + PAD;
        // symmetric window: pairs of taps share a weight, which also keeps the add chains short
        float mx = WIN[RADIUS] * mx_[j], my = WIN[RADIUS] * my_[j], exx = WIN[RADIUS] * mxx_[j];
        float eyy = WIN[RADIUS] * myy_[j], exy = WIN[RADIUS] * mxy_[j];
        #pragma unroll
        for (int k = 1; k <= RADIUS; ++k) {
            const int lo = j - 3 * k, hi = j + 3 * k;
            const float wk = WIN[RADIUS + k];
            mx += wk * (mx_[lo] + mx_[hi]); my += wk * (my_[lo] + my_[hi]); exx += wk * (mxx_[lo] + mxx_[hi]);
            eyy += wk * (myy_[lo] + myy_[hi]); exy += wk * (mxy_[lo] + mxy_[hi]);
        }
        // Products as separate statements (not contracted into fma differently in A and C, B and D), so
        // that identical images give A = C, B = D and S = 1 to rounding.
        float mxx = mx * mx, myy = my * my, mxy = mx * my;
        float sxx = exx - mxx, syy = eyy - myy, sxy = exy - mxy;
        float A = 2.0f * mxy + SSIM_C1, B = 2.0f * sxy + SSIM_C2;
        float C = mxx + myy + SSIM_C1, D = sxx + syy + SSIM_C2;
        // S and its partials written without dividing by A or B (B can be 0).
        float iC = 1.0f / C, iD = 1.0f / D, iCD = iC * iD;
        float S = A * B * iCD;
        const int i = r * n3w + e;
        d0[i] = dscale * (2.0f * my * (B - A) * iCD + 2.0f * mx * S * (iD - iC));
        d1[i] = dscale * (-S * iD);
        d2[i] = dscale * (2.0f * A * iCD);
        float d = x[i] - y[i];
        s_abs += d < 0.0f ? -d : d;
        s_sq += d * d;
        s_dssim += 1.0f - S;   // summing 1 - S keeps 1 - SSIM accurate when SSIM is near 1
    }
    float s[3] = {s_abs, s_sq, s_dssim};
    work_group_sum3(s, red);
    const int group = get_group_id(1) * get_num_groups(0) + get_group_id(0);
    if (lid == 0) { partial[3 * group] = s[0]; partial[3 * group + 1] = s[1]; partial[3 * group + 2] = s[2]; }
}

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void loss_grad(const int n3w, const int h, const float l1scale, GLOBAL_IN x, GLOBAL_IN y,
               GLOBAL_IN d0, GLOBAL_IN d1, GLOBAL_IN d2, GLOBAL_OUT grad,
               __global const uint *frame, const int groups, const float inv_m, GLOBAL_IN partial,
               __global float *stats) {
    __local float a_[LEN], b_[LEN], c_[LEN], red[3 * WG];
    SPAN_RANGES
    VERTICAL_TAPS(off, w)
    for (int j = lid; j < jlo; j += WG) a_[j] = b_[j] = c_[j] = 0.0f;
    for (int j = jhi + lid; j < jend; j += WG) a_[j] = b_[j] = c_[j] = 0.0f;
    #pragma clang loop vectorize(enable)
    for (int j = jlo + lid; j < jhi; j += WG) {
        const int e = g0 - PAD + j;
        float sa = 0.0f, sb = 0.0f, sc = 0.0f;
        #pragma unroll
        for (int k = 0; k < TAPS; ++k) {
            sa += w[k] * d0[off[k] + e]; sb += w[k] * d1[off[k] + e]; sc += w[k] * d2[off[k] + e];
        }
        a_[j] = sa; b_[j] = sb; c_[j] = sc;
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    ITEM_RANGE
    #pragma clang loop vectorize(enable)
    for (int e = e0; e < e1; ++e) {
        const int j = e - g0 + PAD;
        float sa = WIN[RADIUS] * a_[j], sb = WIN[RADIUS] * b_[j], sc = WIN[RADIUS] * c_[j];
        #pragma unroll
        for (int k = 1; k <= RADIUS; ++k) {
            const int lo = j - 3 * k, hi = j + 3 * k;
            const float wk = WIN[RADIUS + k];
            sa += wk * (a_[lo] + a_[hi]); sb += wk * (b_[lo] + b_[hi]); sc += wk * (c_[lo] + c_[hi]);
        }
        const int i = r * n3w + e;
        float xv = x[i], yv = y[i], d = xv - yv;
        grad[i] = (d > 0.0f ? l1scale : (d < 0.0f ? -l1scale : 0.0f)) + sa + 2.0f * xv * sb + yv * sc;
    }
    if (get_group_id(0) == 0 && get_group_id(1) == 0)   // the whole group: add_image_stats has barriers
        add_image_stats(frame, groups, inv_m, partial, stats, red);
}

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void loss_reduce(__global const uint *frame, const int groups, const float inv_m, GLOBAL_IN partial,
                 __global float *stats) {
    __local float red[3 * WG];
    add_image_stats(frame, groups, inv_m, partial, stats, red);
}

__kernel void mask_pixels(const int n_pixels, GLOBAL_IN x, __global const uchar *restrict keep, GLOBAL_OUT out) {
    const int i = get_global_id(0);
    if (i >= n_pixels) return;
    const int k = keep[i];
    for (int c = 0; c < 3; ++c)
        out[3 * i + c] = k ? x[3 * i + c] : 0.0f;   // a select, not a product: 0 * Inf would be NaN
}
