/*
 * moegs CPU compositing kernel: forward and analytic backward of front-to-back Gaussian
 * compositing with one transmittance per group (expert).
 *
 * Plain C99 + OpenMP. No torch and no Python headers: the shared library is loaded with ctypes
 * by moegs/kernels/__init__.py; moegs/render/_cpu.py owns every output buffer (torch tensors) and
 * passes raw pointers. All arrays are C-contiguous; float is IEEE float32.
 *
 * Contract (identical to moegs/render/_torch.py, the test oracle):
 *   - Gaussians are visited in depth order (a stable argsort computed by the caller: `order`).
 *   - Gaussian i touches pixel (x, y), centre p = (x + 0.5, y + 0.5), iff radii[i] > 0 and
 *     |p - mean_i|_inf <= radii[i]. The inclusive pixel box is computed exactly like the torch
 *     reference (float32 ceil/floor), so tiles never change which pixels a Gaussian touches.
 *   - d = p - mean, power = -0.5 (a dx^2 + c dy^2) - b dx dy; skip if power > 0.
 *     alpha = min(ALPHA_MAX, opacity exp(power)); skip if alpha < ALPHA_MIN.
 *   - Group g keeps T_g (starts at 1). If T_g (1 - alpha) < T_MIN the group is finished at this
 *     pixel and the Gaussian is NOT composited; otherwise w = T_g alpha, T_g <- T_g (1 - alpha).
 *   - image[g,y,x,:] = sum w c, alpha[g,y,x] = sum w = 1 - T_g, contrib[i] = sum over pixels of w.
 *
 * Work decomposition
 *   The image is cut into square tiles of `tile` pixels. Each Gaussian is binned into the tiles
 *   its pixel box overlaps; every tile list is sorted by depth because Gaussians are appended in
 *   depth order. A tile is processed by one thread, Gaussian-outer / pixel-inner: for each
 *   Gaussian of the list we visit only the pixels of (its box intersected with the tile), which
 *   is the bounding-box culling, and keep per-pixel state (T, accumulated colour, last
 *   contributor) in thread-local arrays. The per-pixel order of Gaussians is the tile-list order,
 *   i.e. depth order, so the result is the per-pixel front-to-back sum of the contract.
 *
 * Determinism
 *   Every per-Gaussian reduction (contrib, gradients) goes through one slot per (tile, Gaussian)
 *   pair: a tile writes the sum over its pixels (fixed pixel order) into the slot of that pair,
 *   then each Gaussian sums its slots in a fixed order (its tiles, row-major). No atomics and no
 *   per-thread buffers, so results are bit-identical for any thread count and any schedule.
 *
 * Floating point: build WITHOUT -ffast-math and with -ffp-contract=off so that the power/alpha
 * expressions are evaluated exactly like the separate float32 torch ops of the reference (no FMA
 * contraction). Transmittance is carried in double (the reference uses a float64 log-cumsum).
 */

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "moegs_api.h"

/* Bump when any exported signature (this file or hashgrid.c) or saved-state layout changes; the loader
 * checks it. 2: the hash encoding (hashgrid.c) joined the library. */
#define MOEGS_ABI_VERSION 2

/* Constants of the contract. The float ones are the float32 values torch compares against
 * (a Python float compared with a float32 tensor is rounded to float32). */
#define ALPHA_MIN ((float)(1.0 / 255.0))
#define ALPHA_MAX ((float)0.99)
#define T_MIN 1e-4

/* Geometry record of one Gaussian in depth order: mean x, mean y, conic a, b, c, opacity,
 * power cut-off (see below), padding. */
#define GEO 8

/* Cheap exact culling: alpha = opacity exp(power) < ALPHA_MIN whenever
 * power < log(ALPHA_MIN / opacity). We skip the exp (and the pixel) only when power is below that
 * bound minus a margin that dwarfs every float rounding involved (expf, the product, the cast of
 * the bound), so the skipped pixels are exactly pixels the contract skips. */
#define POWER_CUT_MARGIN 1e-4

static float power_cutoff(float opacity) {
    if (!(opacity > 0.0f)) return opacity <= 0.0f ? INFINITY : -INFINITY; /* <= 0: skip all; NaN: none */
    return (float)(log((double)ALPHA_MIN / (double)opacity) - POWER_CUT_MARGIN);
}

/* Below this many items a loop runs on the calling thread: a fork/join costs more than the work
 * (and much more on an oversubscribed machine). */
#define PAR_MIN 16384

/* Error codes (negative return values). */
#define ERR_NOMEM (-1)
#define ERR_GROUP (-2)
#define ERR_ARGS (-3)

static inline int imin(int a, int b) { return a < b ? a : b; }
static inline int imax(int a, int b) { return a > b ? a : b; }

/* Tile t of the row-major tile grid (ntx tiles across): origin (x0, y0) and size w x h pixels. */
typedef struct {
    int x0, y0, w, h, npix;
} Tile;

static inline Tile tile_at(int64_t t, int ntx, int tile, int W, int H) {
    Tile r;
    r.x0 = (int)(t % ntx) * tile;
    r.y0 = (int)(t / ntx) * tile;
    r.w = imin(tile, W - r.x0);
    r.h = imin(tile, H - r.y0);
    r.npix = r.w * r.h;
    return r;
}

/* Gaussian k (depth order) as a tile sees it: its geometry record and its pixel box intersected
 * with the tile, in tile-local pixels [lx0, lx1] x [ly0, ly1]. */
typedef struct {
    float mx, my, ca, cb, cc, op, pcut;
    int lx0, lx1, ly0, ly1;
} Footprint;

static inline Footprint footprint(const float *geo, const int32_t *box, int64_t k, Tile r) {
    const float *g = geo + k * GEO;
    const int32_t *b = box + 4 * k;
    Footprint f;
    f.mx = g[0]; f.my = g[1]; f.ca = g[2]; f.cb = g[3]; f.cc = g[4]; f.op = g[5]; f.pcut = g[6];
    f.lx0 = imax(b[0], r.x0) - r.x0; f.lx1 = imin(b[1], r.x0 + r.w - 1) - r.x0;
    f.ly0 = imax(b[2], r.y0) - r.y0; f.ly1 = imin(b[3], r.y0 + r.h - 1) - r.y0;
    return f;
}

/* Checks the image arguments of the forward and backward; returns the tile count and sets *ntx,
 * or ERR_ARGS. */
static int64_t tile_grid(int64_t n, int64_t d, int32_t G, int32_t W, int32_t H, int32_t tile, int *ntx) {
    if (n < 0 || d < 1 || G < 1 || W < 1 || H < 1 || tile < 1) return ERR_ARGS;
    *ntx = (W + tile - 1) / tile;
    return (int64_t)(*ntx) * ((H + tile - 1) / tile);
}

MOEGS_API int moegs_abi_version(void) { return MOEGS_ABI_VERSION; }

/* Number of OpenMP threads this library would use by default (diagnostics only). */
MOEGS_API int moegs_max_threads(void) {
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

/* Stub so the file can also be built as a CPython "extension module" by setuptools (some
 * platforms' linkers want PyInit_<name> exported). It is never meant to be imported: doing so
 * raises SystemError. The real entry points are the moegs_* symbols, used through ctypes. */
MOEGS_API void *PyInit__cpu(void) { return 0; }

/*
 * Row culling (exact): on a pixel row with offset dy, the pixels that can pass the alpha test
 * satisfy power(dx) >= pcut, i.e. the quadratic
 *     (a/2) dx^2 + (b dy) dx + (c/2 dy^2 + pcut) <= 0,
 * an interval of dx when a > 0. We solve it in double with pcut lowered by a margin that covers
 * the float32 rounding of `power` (relative to the size of its terms on this row), then widen
 * the pixel range by one pixel on each side. Pixels outside the returned [lo, hi] (tile-local)
 * are therefore pixels whose alpha test fails, so skipping them changes nothing. When the conic
 * is not usable (a <= 0, non-finite values) the whole range is kept. Returns 0 if the row is
 * certainly empty.
 */
static inline int row_span(float dy, float mx, float ca, float cb, float cc, float pcut, int tx0,
                           int lx0, int lx1, int *lo, int *hi) {
    *lo = lx0;
    *hi = lx1;
    if (!(ca > 0.0f) || !isfinite(pcut) || !isfinite(cb) || !isfinite(cc)) return 1;
    /* largest |dx| on this row segment bounds the size of the terms of power */
    const double dxa = fabs((double)tx0 + lx0 + 0.5 - mx), dxb = fabs((double)tx0 + lx1 + 0.5 - mx);
    const double mdx = dxa > dxb ? dxa : dxb, ady = fabs((double)dy);
    const double terms = 0.5 * fabs((double)ca) * mdx * mdx + 0.5 * fabs((double)cc) * ady * ady +
                         fabs((double)cb) * mdx * ady;
    const double cut = (double)pcut - 1e-3 - 4e-6 * terms;
    const double qa = 0.5 * (double)ca, qb = (double)cb * dy, qc = 0.5 * (double)cc * dy * dy + cut;
    const double disc = qb * qb - 4.0 * qa * qc;
    if (disc < 0.0) return 0;
    const double sq = sqrt(disc);
    /* pixel x has dx = x + 0.5 - mx, so x = mx - 0.5 + dx */
    const double xlo = (double)mx - 0.5 + (-qb - sq) / (2.0 * qa) - (double)tx0;
    const double xhi = (double)mx - 0.5 + (-qb + sq) / (2.0 * qa) - (double)tx0;
    if (xlo > (double)lx1 + 1.0 || xhi < (double)lx0 - 1.0) return 0;
    if (xlo - 1.0 > (double)lx0) *lo = (int)floor(xlo) - 1;
    if (xhi + 1.0 < (double)lx1) *hi = (int)ceil(xhi) + 1;
    if (*lo < lx0) *lo = lx0;
    if (*hi > lx1) *hi = lx1;
    return *lo <= *hi;
}

/* Row ly (tile-local) of a footprint: the pixel-centre offset dy and the tile-local pixels [lo, hi]
 * that can pass the alpha test (row_span); lo > hi when none can. */
typedef struct {
    float dy;
    int lo, hi;
} Row;

static inline Row footprint_row(const Footprint *f, Tile r, int ly) {
    Row row;
    row.dy = ((float)(r.y0 + ly) + 0.5f) - f->my;
    if (!row_span(row.dy, f->mx, f->ca, f->cb, f->cc, f->pcut, r.x0, f->lx0, f->lx1, &row.lo, &row.hi)) {
        row.lo = 1;
        row.hi = 0;
    }
    return row;
}

/* The Gaussian's exponent at pixel lx (tile-local) of a row with offset dy, in the float32 operation
 * order of the torch reference; *dx is the pixel centre's x offset. */
static inline float footprint_power(const Footprint *f, Tile r, int lx, float dy, float *dx) {
    *dx = ((float)(r.x0 + lx) + 0.5f) - f->mx;
    return -0.5f * (f->ca * *dx * *dx + f->cc * dy * dy) - f->cb * *dx * dy;
}

/* Inclusive pixel box of a Gaussian, exactly as _torch._bbox_pixels computes it in float32:
 *   x0 = clamp_min(ceil(mx - r - 0.5), 0),  x1 = clamp_max(floor(mx + r - 0.5), W - 1).
 * Returns 0 (and an empty box) when the Gaussian touches no pixel. */
static int pixel_box(float mx, float my, int32_t radius, int W, int H, int32_t *box) {
    box[0] = 0; box[1] = -1; box[2] = 0; box[3] = -1;
    if (radius <= 0 || !isfinite(mx) || !isfinite(my)) return 0;
    const float r = (float)radius;
    float fx0 = ceilf(mx - r - 0.5f), fx1 = floorf(mx + r - 0.5f);
    float fy0 = ceilf(my - r - 0.5f), fy1 = floorf(my + r - 0.5f);
    /* clamp in float before converting so that huge coordinates cannot overflow an int */
    fx0 = fmaxf(fminf(fx0, (float)W), 0.0f);
    fy0 = fmaxf(fminf(fy0, (float)H), 0.0f);
    fx1 = fminf(fmaxf(fx1, -1.0f), (float)(W - 1));
    fy1 = fminf(fmaxf(fy1, -1.0f), (float)(H - 1));
    const int x0 = (int)fx0, x1 = (int)fx1, y0 = (int)fy0, y1 = (int)fy1;
    if (x0 > x1 || y0 > y1) return 0;
    box[0] = x0; box[1] = x1; box[2] = y0; box[3] = y1;
    return 1;
}

/*
 * Step 1: gather the inputs into depth order and count the (tile, Gaussian) pairs.
 *
 *   order    [n]      int64   depth order (stable argsort of depths); entry k = original index
 *   means    [n,2], conics [n,3], opac [n], colors [n,d]   float32, original order
 *   radii    [n] int32, groups [n] int32 or NULL (all group 0)
 * Outputs (sorted position k = depth rank):
 *   geo      [n,8] float32   (mx, my, a, b, c, opacity, power cut-off, 0)
 *   box      [n,4] int32     inclusive pixel box (x0, x1, y0, y1); empty = (0,-1,0,-1)
 *   grp      [n]   int32     group
 *   col      [n,d] float32   colours
 *   gstart   [n+1] int64     first pair of Gaussian k in Gaussian-major pair order
 *   tile_off [ntiles+1] int64  first list position of each tile (row-major tiles)
 * Returns the total number of pairs (>= 0) or a negative error code.
 */
MOEGS_API int64_t moegs_prepare(int64_t n, int64_t d, int32_t num_groups, int32_t W, int32_t H,
                                int32_t tile, int32_t nthreads, const int64_t *order,
                                const float *means, const float *conics, const float *opac,
                                const float *colors, const int32_t *radii, const int32_t *groups,
                                float *geo, int32_t *box, int32_t *grp, float *col,
                                int64_t *gstart, int64_t *tile_off) {
    if (n < 0 || d < 1 || num_groups < 1 || W < 1 || H < 1 || tile < 1) return ERR_ARGS;
    const int ntx = (W + tile - 1) / tile, nty = (H + tile - 1) / tile;
    const int64_t ntiles = (int64_t)ntx * nty;
    int bad_group = 0;
    if (nthreads < 1) nthreads = 1;

#pragma omp parallel for num_threads(nthreads) schedule(static) reduction(| : bad_group) if (n > PAR_MIN)
    for (int64_t k = 0; k < n; ++k) {
        const int64_t i = order[k];
        float *g = geo + k * GEO;
        g[0] = means[2 * i]; g[1] = means[2 * i + 1];
        g[2] = conics[3 * i]; g[3] = conics[3 * i + 1]; g[4] = conics[3 * i + 2];
        g[5] = opac[i];
        g[6] = power_cutoff(g[5]);
        g[7] = 0.0f;
        memcpy(col + k * d, colors + i * d, (size_t)d * sizeof(float));
        const int32_t gi = groups ? groups[i] : 0;
        if (gi < 0 || gi >= num_groups) bad_group = 1;
        grp[k] = gi;
        int32_t *b = box + 4 * k;
        int64_t count = 0;
        if (pixel_box(g[0], g[1], radii[i], W, H, b))
            count = (int64_t)(b[1] / tile - b[0] / tile + 1) * (b[3] / tile - b[2] / tile + 1);
        gstart[k + 1] = count;
    }
    if (bad_group) return ERR_GROUP;

    /* prefix sums (serial, O(n + pairs)) */
    gstart[0] = 0;
    for (int64_t k = 0; k < n; ++k) gstart[k + 1] += gstart[k];
    memset(tile_off, 0, (size_t)(ntiles + 1) * sizeof(int64_t));
    for (int64_t k = 0; k < n; ++k) {
        const int32_t *b = box + 4 * k;
        if (b[0] > b[1]) continue;
        for (int ty = b[2] / tile; ty <= b[3] / tile; ++ty)
            for (int tx = b[0] / tile; tx <= b[1] / tile; ++tx) tile_off[(int64_t)ty * ntx + tx + 1]++;
    }
    for (int64_t t = 0; t < ntiles; ++t) tile_off[t + 1] += tile_off[t];
    return gstart[n];
}

/* Fill the tile lists (list[pos] = sorted Gaussian k) and the Gaussian-major pair -> list
 * position map (pairpos[gstart[k] + j] = pos of the j-th tile of k, tiles row-major). Appending
 * Gaussians in depth order keeps every tile list depth-sorted. Serial: O(pairs), cheap. */
static int fill_lists(int64_t n, int32_t W, int32_t tile, const int32_t *box, const int64_t *gstart,
                      const int64_t *tile_off, int64_t ntiles, int32_t *list, int64_t *pairpos) {
    const int ntx = (W + tile - 1) / tile;
    int64_t *cursor = (int64_t *)malloc((size_t)(ntiles > 0 ? ntiles : 1) * sizeof(int64_t));
    if (!cursor) return ERR_NOMEM;
    memcpy(cursor, tile_off, (size_t)ntiles * sizeof(int64_t));
    for (int64_t k = 0; k < n; ++k) {
        const int32_t *b = box + 4 * k;
        if (b[0] > b[1]) continue;
        int64_t j = gstart[k];
        for (int ty = b[2] / tile; ty <= b[3] / tile; ++ty)
            for (int tx = b[0] / tile; tx <= b[1] / tile; ++tx) {
                const int64_t pos = cursor[(int64_t)ty * ntx + tx]++;
                list[pos] = (int32_t)k;
                pairpos[j++] = pos;
            }
    }
    free(cursor);
    return 0;
}

/*
 * Step 2: forward.
 *   Inputs: the outputs of moegs_prepare and `total` (its return value).
 *   list [total] int32, pairpos [total] int64: filled here, kept by the caller for the backward.
 *   image [G,H,W,d], alpha [G,H,W], contrib [n] (ORIGINAL order) float32.
 *   tfinal [G,H,W] float64: transmittance after the last composited Gaussian.
 *   last [G,H,W] int32: position in the pixel's tile list of the last composited Gaussian of the
 *        group, -1 if none. Together with tfinal this is all the backward needs per pixel.
 * Returns 0 or a negative error code.
 */
MOEGS_API int moegs_forward(int64_t n, int64_t d, int32_t G, int32_t W, int32_t H, int32_t tile,
                            int32_t nthreads, const int64_t *order, const float *geo, const int32_t *box,
                            const int32_t *grp, const float *col, const int64_t *gstart,
                            const int64_t *tile_off, int64_t total, int32_t *list, int64_t *pairpos,
                            float *image, float *alpha, float *contrib, double *tfinal, int32_t *last) {
    int ntx;
    const int64_t ntiles = tile_grid(n, d, G, W, H, tile, &ntx);
    if (ntiles < 0) return ERR_ARGS;
    if (nthreads < 1) nthreads = 1;
    if (fill_lists(n, W, tile, box, gstart, tile_off, ntiles, list, pairpos)) return ERR_NOMEM;

    /* one float per pair: sum over the tile's pixels of the weights of that Gaussian */
    float *slot = (float *)malloc((size_t)(total > 0 ? total : 1) * sizeof(float));
    if (!slot) return ERR_NOMEM;
    int err = 0;
    const int64_t npmax = (int64_t)tile * tile;

#pragma omp parallel num_threads(nthreads)
    {
        /* thread-local per-(group, pixel) state of the current tile, index s = g * npix + p */
        double *T = (double *)malloc((size_t)(G * npmax) * sizeof(double));
        float *acc = (float *)malloc((size_t)(G * npmax * d) * sizeof(float));
        int32_t *lst = (int32_t *)malloc((size_t)(G * npmax) * sizeof(int32_t));
        unsigned char *done = (unsigned char *)malloc((size_t)(G * npmax));
        int64_t *live_g = (int64_t *)malloc((size_t)G * sizeof(int64_t));
        const int ok = T && acc && lst && done && live_g;
        if (!ok) flag_error(&err);

#pragma omp for schedule(dynamic, 1)
        for (int64_t t = 0; t < ntiles; ++t) {
            if (!ok) continue;
            const Tile r = tile_at(t, ntx, tile, W, H);
            const int64_t S = (int64_t)G * r.npix;
            for (int64_t s = 0; s < S; ++s) { T[s] = 1.0; lst[s] = -1; done[s] = 0; }
            memset(acc, 0, (size_t)(S * d) * sizeof(float));
            int64_t live = S; /* (group, pixel) pairs not finished yet */
            for (int gi = 0; gi < G; ++gi) live_g[gi] = r.npix; /* the same, per group */
            const int64_t start = tile_off[t], end = tile_off[t + 1];
            int64_t pos = start;
            for (; pos < end && live > 0; ++pos) {
                const int32_t k = list[pos];
                const int32_t gk = grp[k];
                /* every pixel of this Gaussian's group is finished: it composites nothing here
                 * (a separate render of the group would already have retired the tile) */
                if (live_g[gk] == 0) { slot[pos] = 0.0f; continue; }
                const Footprint f = footprint(geo, box, k, r);
                const float *ck = col + (int64_t)k * d;
                float wsum = 0.0f;
                for (int ly = f.ly0; ly <= f.ly1; ++ly) {
                    const Row row = footprint_row(&f, r, ly);
                    const float dy = row.dy;
                    for (int lx = row.lo; lx <= row.hi; ++lx) {
                        const int64_t s = (int64_t)gk * r.npix + ly * r.w + lx;
                        if (done[s]) continue;
                        float dx;
                        const float power = footprint_power(&f, r, lx, dy, &dx);
                        if (power > 0.0f || power < f.pcut) continue;
                        float a = f.op * expf(power);
                        if (a > ALPHA_MAX) a = ALPHA_MAX;
                        if (a < ALPHA_MIN) continue;
                        const double tn = T[s] * (1.0 - (double)a);
                        if (tn < T_MIN) { /* group finished here; this Gaussian is not composited */
                            done[s] = 1;
                            --live;
                            --live_g[gk];
                            continue;
                        }
                        const float w = a * (float)T[s];
                        float *as = acc + s * d;
                        for (int64_t c = 0; c < d; ++c) as[c] += w * ck[c];
                        T[s] = tn;
                        lst[s] = (int32_t)(pos - start);
                        wsum += w;
                    }
                }
                slot[pos] = wsum;
            }
            for (; pos < end; ++pos) slot[pos] = 0.0f; /* tile retired early */

            /* write the tile out */
            for (int gi = 0; gi < G; ++gi)
                for (int ly = 0; ly < r.h; ++ly)
                    for (int lx = 0; lx < r.w; ++lx) {
                        const int64_t s = (int64_t)gi * r.npix + ly * r.w + lx;
                        const int64_t o = ((int64_t)gi * H + r.y0 + ly) * W + r.x0 + lx;
                        memcpy(image + o * d, acc + s * d, (size_t)d * sizeof(float));
                        alpha[o] = (float)(1.0 - T[s]);
                        tfinal[o] = T[s];
                        last[o] = lst[s];
                    }
        }
        free(T); free(acc); free(lst); free(done); free(live_g);
    }
    if (err) { free(slot); return ERR_NOMEM; }

    /* contrib: each Gaussian sums its slots in its own (fixed) tile order */
#pragma omp parallel for num_threads(nthreads) schedule(static) if (total > PAR_MIN)
    for (int64_t k = 0; k < n; ++k) {
        float sum = 0.0f;
        for (int64_t j = gstart[k]; j < gstart[k + 1]; ++j) sum += slot[pairpos[j]];
        contrib[order[k]] = sum;
    }
    free(slot);
    return 0;
}

/*
 * Step 3: backward (3DGS-style reverse traversal, per pixel and group).
 *
 * For one pixel and group, with composited Gaussians j (front to back), T_j the transmittance in
 * front of j, w_j = alpha_j T_j, T_f the final transmittance, C = sum w_j c_j, A = sum w_j = 1 - T_f:
 *   dC/dc_j     = w_j
 *   dC/dalpha_j = T_j c_j - B_j / (1 - alpha_j),   B_j = sum_{i > j} w_i c_i  (colour behind j)
 *   dA/dalpha_j = T_f / (1 - alpha_j)
 * Walking back from the last composited Gaussian, T_j = T_{j+1} / (1 - alpha_j) and B grows by
 * w_j c_j. Then, with alpha = opacity e, e = exp(power) (when the ALPHA_MAX clamp is not active;
 * otherwise alpha is a constant and only the colour gradient flows):
 *   dalpha/dopacity = e,  dalpha/dpower = alpha,
 *   dpower/da = -dx^2/2,  dpower/db = -dx dy,  dpower/dc = -dy^2/2,
 *   dpower/dmx = a dx + b dy,  dpower/dmy = b dx + c dy      (d = p - mean).
 *
 * Inputs: the saved forward state and grad_image [G,H,W,d], grad_alpha [G,H,W] (float32).
 * Outputs (ORIGINAL order, fully overwritten): grad_means [n,2], grad_conics [n,3],
 * grad_opac [n], grad_colors [n,d].
 */
MOEGS_API int moegs_backward(int64_t n, int64_t d, int32_t G, int32_t W, int32_t H, int32_t tile,
                             int32_t nthreads, const int64_t *order, const float *geo, const int32_t *box,
                             const int32_t *grp, const float *col, const int64_t *gstart,
                             const int64_t *tile_off, int64_t total, const int32_t *list,
                             const int64_t *pairpos, const double *tfinal, const int32_t *last,
                             const float *grad_image, const float *grad_alpha, float *grad_means,
                             float *grad_conics, float *grad_opac, float *grad_colors) {
    int ntx;
    const int64_t ntiles = tile_grid(n, d, G, W, H, tile, &ntx);
    if (ntiles < 0) return ERR_ARGS;
    if (nthreads < 1) nthreads = 1;
    /* per pair: d(mx, my), d(a, b, c), d(opacity), d(colour)[d] */
    const int64_t stride = 6 + d;
    float *slot = (float *)malloc((size_t)(total > 0 ? total : 1) * stride * sizeof(float));
    if (!slot) return ERR_NOMEM;
    int err = 0;
    const int64_t npmax = (int64_t)tile * tile;

#pragma omp parallel num_threads(nthreads)
    {
        double *T = (double *)malloc((size_t)(G * npmax) * sizeof(double));
        double *Tf = (double *)malloc((size_t)(G * npmax) * sizeof(double));
        double *B = (double *)malloc((size_t)(G * npmax * d) * sizeof(double));
        float *gi_loc = (float *)malloc((size_t)(G * npmax * d) * sizeof(float));
        float *ga_loc = (float *)malloc((size_t)(G * npmax) * sizeof(float));
        int32_t *lst = (int32_t *)malloc((size_t)(G * npmax) * sizeof(int32_t));
        double *gcol = (double *)malloc((size_t)d * sizeof(double));
        int32_t *maxlast_g = (int32_t *)malloc((size_t)G * sizeof(int32_t));
        const int ok = T && Tf && B && gi_loc && ga_loc && lst && gcol && maxlast_g;
        if (!ok) flag_error(&err);

#pragma omp for schedule(dynamic, 1)
        for (int64_t t = 0; t < ntiles; ++t) {
            if (!ok) continue;
            const Tile r = tile_at(t, ntx, tile, W, H);
            const int64_t start = tile_off[t], end = tile_off[t + 1];
            /* load the per-pixel state of the tile */
            int32_t maxlast = -1;
            for (int g = 0; g < G; ++g) {
                maxlast_g[g] = -1;
                for (int ly = 0; ly < r.h; ++ly)
                    for (int lx = 0; lx < r.w; ++lx) {
                        const int64_t s = (int64_t)g * r.npix + ly * r.w + lx;
                        const int64_t o = ((int64_t)g * H + r.y0 + ly) * W + r.x0 + lx;
                        T[s] = Tf[s] = tfinal[o];
                        lst[s] = last[o];
                        if (last[o] > maxlast_g[g]) maxlast_g[g] = last[o];
                        ga_loc[s] = grad_alpha[o];
                        memcpy(gi_loc + s * d, grad_image + o * d, (size_t)d * sizeof(float));
                    }
                if (maxlast_g[g] > maxlast) maxlast = maxlast_g[g];
            }
            memset(B, 0, (size_t)((int64_t)G * r.npix * d) * sizeof(double));
            /* Gaussians after the last contributor of every pixel get nothing from this tile */
            for (int64_t pos = start + maxlast + 1; pos < end; ++pos)
                memset(slot + pos * stride, 0, (size_t)stride * sizeof(float));

            for (int32_t j = maxlast; j >= 0; --j) {
                const int64_t pos = start + j;
                const int32_t k = list[pos];
                const int32_t gk = grp[k];
                float *sl = slot + pos * stride;
                if (j > maxlast_g[gk]) { /* behind the last contributor of all its group's pixels */
                    memset(sl, 0, (size_t)stride * sizeof(float));
                    continue;
                }
                const Footprint f = footprint(geo, box, k, r);
                const float *ck = col + (int64_t)k * d;
                double gmx = 0, gmy = 0, ga = 0, gb = 0, gc = 0, gop = 0;
                for (int64_t c = 0; c < d; ++c) gcol[c] = 0.0;
                for (int ly = f.ly0; ly <= f.ly1; ++ly) {
                    const Row row = footprint_row(&f, r, ly);
                    const float dy = row.dy;
                    for (int lx = row.lo; lx <= row.hi; ++lx) {
                        const int64_t s = (int64_t)gk * r.npix + ly * r.w + lx;
                        if (j > lst[s]) continue; /* behind this pixel's last contributor */
                        float dx; /* alpha recomputed exactly as in the forward */
                        const float power = footprint_power(&f, r, lx, dy, &dx);
                        if (power > 0.0f || power < f.pcut) continue;
                        const float e = expf(power);
                        const float raw = f.op * e;
                        const int clamped = raw > ALPHA_MAX;
                        const float a = clamped ? ALPHA_MAX : raw;
                        if (a < ALPHA_MIN) continue;
                        const double inv_om = 1.0 / (1.0 - (double)a); /* 1 / (1 - alpha_j) */
                        const double Tj = T[s] * inv_om; /* transmittance in front of j */
                        T[s] = Tj;
                        const double w = (double)a * Tj;
                        const float *gp = gi_loc + s * d;
                        double *Bs = B + s * d;
                        double dot_c = 0.0, dot_b = 0.0;
                        for (int64_t c = 0; c < d; ++c) {
                            gcol[c] += w * gp[c];
                            dot_c += (double)ck[c] * gp[c];
                            dot_b += Bs[c] * gp[c];
                            Bs[c] += w * ck[c];
                        }
                        if (clamped) continue; /* d alpha / d (opacity, power) = 0 */
                        const double dal = Tj * dot_c + ((double)ga_loc[s] * Tf[s] - dot_b) * inv_om;
                        gop += (double)e * dal;
                        const double dp = (double)a * dal; /* dL/dpower */
                        ga += -0.5 * (double)dx * dx * dp;
                        gb += -(double)dx * dy * dp;
                        gc += -0.5 * (double)dy * dy * dp;
                        gmx += ((double)f.ca * dx + (double)f.cb * dy) * dp;
                        gmy += ((double)f.cb * dx + (double)f.cc * dy) * dp;
                    }
                }
                sl[0] = (float)gmx; sl[1] = (float)gmy;
                sl[2] = (float)ga; sl[3] = (float)gb; sl[4] = (float)gc;
                sl[5] = (float)gop;
                for (int64_t c = 0; c < d; ++c) sl[6 + c] = (float)gcol[c];
            }
        }
        free(T); free(Tf); free(B); free(gi_loc); free(ga_loc); free(lst); free(gcol); free(maxlast_g);
    }
    if (err) { free(slot); return ERR_NOMEM; }

    /* reduce the pair slots per Gaussian in a fixed order and scatter to the original order */
#pragma omp parallel num_threads(nthreads) if (total > PAR_MIN)
    {
        double *acc = (double *)malloc((size_t)stride * sizeof(double));
        if (!acc) flag_error(&err);
#pragma omp for schedule(static)
        for (int64_t k = 0; k < n; ++k) {
            if (!acc) continue;
            for (int64_t c = 0; c < stride; ++c) acc[c] = 0.0;
            for (int64_t j = gstart[k]; j < gstart[k + 1]; ++j) {
                const float *sl = slot + pairpos[j] * stride;
                for (int64_t c = 0; c < stride; ++c) acc[c] += sl[c];
            }
            const int64_t i = order[k];
            grad_means[2 * i] = (float)acc[0]; grad_means[2 * i + 1] = (float)acc[1];
            grad_conics[3 * i] = (float)acc[2]; grad_conics[3 * i + 1] = (float)acc[3];
            grad_conics[3 * i + 2] = (float)acc[4];
            grad_opac[i] = (float)acc[5];
            for (int64_t c = 0; c < d; ++c) grad_colors[i * d + c] = (float)acc[6 + c];
        }
        free(acc);
    }
    free(slot);
    return err ? ERR_NOMEM : 0;
}
