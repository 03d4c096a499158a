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
 *   is the bounding-box culling, four pixels of a row at a time (see Lanes), and keep per-pixel
 *   state (T, accumulated colour, last contributor) in thread-local arrays. The per-pixel order of
 *   Gaussians is the tile-list order, i.e. depth order, so the result is the per-pixel
 *   front-to-back sum of the contract.
 *
 * Determinism
 *   Every per-Gaussian reduction (contrib, gradients) goes through one slot per (tile, Gaussian)
 *   pair: a tile writes the sum over its pixels (fixed lane and pixel order) into the slot of that pair,
 *   then each Gaussian sums its slots in a fixed order (its tiles, row-major). No atomics and no
 *   per-thread buffers, so results are bit-identical for any thread count and any schedule.
 *
 * Floating point: build WITHOUT -ffast-math and with -ffp-contract=off so that the power
 * expression is evaluated exactly like the separate float32 torch ops of the reference (no FMA
 * contraction). exp is a vectorised polynomial within about 1 ulp of expf (exp_lanes), so alpha may
 * differ from the reference's by an ulp. Transmittance is carried in double (the reference uses a
 * float64 log-cumsum).
 */

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "moegs_api.h"

/* Bump when any exported signature (this file, project.c or hashgrid.c) or saved-state layout changes;
 * the loader checks it. 2: the hash encoding (hashgrid.c) joined the library; 3: the projection
 * (project.c). */
#define MOEGS_ABI_VERSION 3

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
 * bound minus a margin that dwarfs every float rounding involved (the exp, the product, the cast of
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
 * Lanes. The per-pixel work runs four pixels of a tile row at a time (GCC/clang vector extensions):
 * float lanes for the contract's float32 exponent and alpha, double lanes for the transmittance and
 * the backward's sums. Per-Gaussian sums are kept per lane and added lane by lane at the end of the
 * Gaussian's footprint, so results do not depend on the thread count. The tile functions are built
 * twice on x86-64 Linux (AVX2 and the baseline) and the loader picks one per CPU at load time.
 */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__linux__)
#define LANE_CLONES __attribute__((target_clones("avx2", "default")))
#pragma GCC diagnostic ignored "-Wpsabi" /* 32-byte vectors in always-inlined helpers only */
#else
#define LANE_CLONES
#endif
#define LANES 4
#define INLINE static inline __attribute__((always_inline))

typedef float f4 __attribute__((vector_size(16)));
typedef int32_t i4 __attribute__((vector_size(16)));
typedef double d4 __attribute__((vector_size(32)));
typedef int64_t l4 __attribute__((vector_size(32)));

INLINE f4 f4_splat(float v) { return (f4){v, v, v, v}; }
INLINE d4 d4_splat(double v) { return (d4){v, v, v, v}; }
INLINE f4 f4_load(const float *p) { f4 v; memcpy(&v, p, sizeof v); return v; }
INLINE void f4_store(float *p, f4 v) { memcpy(p, &v, sizeof v); }
INLINE d4 d4_load(const double *p) { d4 v; memcpy(&v, p, sizeof v); return v; }
INLINE void d4_store(double *p, d4 v) { memcpy(p, &v, sizeof v); }
INLINE i4 i4_load(const int32_t *p) { i4 v; memcpy(&v, p, sizeof v); return v; }
INLINE void i4_store(int32_t *p, i4 v) { memcpy(p, &v, sizeof v); }
/* m ? a : b per lane (m: all ones or zero per lane) */
INLINE f4 f4_sel(i4 m, f4 a, f4 b) { return (f4)(((i4)a & m) | ((i4)b & ~m)); }
INLINE d4 d4_sel(l4 m, d4 a, d4 b) { return (d4)(((l4)a & m) | ((l4)b & ~m)); }
INLINE i4 i4_sel(i4 m, i4 a, i4 b) { return (a & m) | (b & ~m); }
INLINE l4 wide(i4 m) { return __builtin_convertvector(m, l4); }
INLINE i4 narrow(l4 m) { return __builtin_convertvector(m, i4); }
INLINE d4 d4_of(f4 v) { return __builtin_convertvector(v, d4); }
INLINE f4 f4_of(d4 v) { return __builtin_convertvector(v, f4); }
INLINE int any(i4 m) {
    uint64_t w[2];
    memcpy(w, &m, sizeof w);
    return (w[0] | w[1]) != 0;
}
INLINE int count(i4 m) { return -(m[0] + m[1] + m[2] + m[3]); }
INLINE double d4_sum(d4 v) { return ((v[0] + v[1]) + v[2]) + v[3]; }
INLINE float f4_sum(f4 v) { return ((v[0] + v[1]) + v[2]) + v[3]; }

/* exp of float lanes: Cody-Waite reduction x = n ln2 + r, |r| <= ln2/2, e^r = 1 + r + r^2 q(r) with
 * the degree-5 minimax q of Cephes' expf, evaluated in Estrin form (a short dependency chain), scaled
 * by 2^n. About 1 ulp from expf; the contract only uses lanes in [log(ALPHA_MIN), 0], the others are
 * clamped to [-87, 0] (NaN to 0) so that no lane overflows the exponent. */
INLINE f4 exp_lanes(f4 x) {
    const f4 lo = f4_splat(-87.0f), hi = f4_splat(0.0f);
    x = f4_sel(x < lo, lo, x);
    x = f4_sel(x > hi, hi, x);
    x = f4_sel(x == x, x, hi);
    const f4 shift = f4_splat(12582912.0f); /* 1.5 * 2^23: adding it rounds to an integer */
    const f4 n = (x * f4_splat(1.44269504088896341f) + shift) - shift;
    const f4 r = (x - n * f4_splat(0.693359375f)) - n * f4_splat(-2.12194440e-4f);
    const f4 r2 = r * r;
    const f4 q01 = f4_splat(5.0000001201e-1f) + f4_splat(1.6666665459e-1f) * r;
    const f4 q23 = f4_splat(4.1665795894e-2f) + f4_splat(8.3334519073e-3f) * r;
    const f4 q45 = f4_splat(1.3981999507e-3f) + f4_splat(1.9875691500e-4f) * r;
    const f4 q = q01 + r2 * (q23 + r2 * q45);
    const f4 p = (f4_splat(1.0f) + r) + r2 * q;
    const i4 scale = (__builtin_convertvector(n, i4) + 127) << 23;
    return p * (f4)scale;
}

/* One 4-pixel chunk of a footprint row: lanes cx .. cx+3 (tile-local), the mask of lanes inside
 * [lx0, lx1], their x offsets dx and the exponent, in the float32 operation order of the reference. */
typedef struct {
    i4 in;
    f4 dx, power;
} Chunk;

INLINE Chunk chunk_at(const Footprint *f, Tile r, int cx, float dy) {
    Chunk c;
    const i4 lx = (i4){cx, cx + 1, cx + 2, cx + 3};
    c.in = (lx >= f->lx0) & (lx <= f->lx1);
    c.dx = (__builtin_convertvector(lx + r.x0, f4) + f4_splat(0.5f)) - f4_splat(f->mx);
    const f4 ca = f4_splat(f->ca), cb = f4_splat(f->cb);
    const float cdd = f->cc * dy * dy;
    c.power = f4_splat(-0.5f) * (ca * c.dx * c.dx + f4_splat(cdd)) - cb * c.dx * f4_splat(dy);
    return c;
}

/* Lanes whose exponent can pass the alpha test: not (power > 0 or power < cut-off), as the scalar
 * contract tests it (a NaN exponent is not skipped there either). */
INLINE i4 may_pass(const Footprint *f, Chunk c) {
    return c.in & ~(c.power > f4_splat(0.0f)) & ~(c.power < f4_splat(f->pcut));
}

/* Ask for the per-Gaussian records of the Gaussian `ahead` list entries away: the tile lists visit
 * Gaussians in depth order, i.e. scattered through memory, and every pair starts with these loads. */
#define PREFETCH_AHEAD 6
INLINE void prefetch_gaussian(const float *geo, const int32_t *box, const int32_t *grp, const float *col,
                              int64_t d, int32_t k) {
    __builtin_prefetch(geo + (int64_t)k * GEO);
    __builtin_prefetch(box + 4 * (int64_t)k);
    __builtin_prefetch(grp + k);
    __builtin_prefetch(col + (int64_t)k * d);
}

/* Row stride of the per-tile pixel state: the tile width rounded up to whole chunks. */
static inline int lane_stride(int tile) { return (tile + LANES - 1) / LANES * LANES; }

/* Forward of one tile (see moegs_forward). State, per (group, pixel) s = g * np + ly * stride + lx:
 * T (double), acc (float, channel-major: (g * d + c) * np + ...), lst, done (0 / -1). */
LANE_CLONES
static void forward_tile(Tile r, int G, int64_t d, int tile, const float *geo, const int32_t *box,
                         const int32_t *grp, const float *col, const int32_t *list, int64_t start,
                         int64_t end, float *slot, double *T, float *acc, int32_t *lst, int32_t *done,
                         int64_t *live_g) {
    const int stride = lane_stride(tile);
    const int64_t np = (int64_t)tile * stride;
    for (int64_t s = 0; s < G * np; ++s) { T[s] = 1.0; lst[s] = -1; done[s] = 0; }
    memset(acc, 0, (size_t)(G * d * np) * sizeof(float));
    int64_t live = (int64_t)G * r.npix;
    for (int gi = 0; gi < G; ++gi) live_g[gi] = r.npix;
    int64_t pos = start;
    for (; pos < end && live > 0; ++pos) {
        if (pos + PREFETCH_AHEAD < end) prefetch_gaussian(geo, box, grp, col, d, list[pos + PREFETCH_AHEAD]);
        const int32_t k = list[pos];
        const int32_t gk = grp[k];
        if (live_g[gk] == 0) { slot[pos] = 0.0f; continue; }
        const Footprint f = footprint(geo, box, k, r);
        const float *ck = col + (int64_t)k * d;
        const i4 index = (i4){0, 0, 0, 0} + (int32_t)(pos - start);
        f4 wsum = f4_splat(0.0f);
        for (int ly = f.ly0; ly <= f.ly1; ++ly) {
            const float dy = ((float)(r.y0 + ly) + 0.5f) - f.my;
            for (int cx = f.lx0 / LANES * LANES; cx <= f.lx1; cx += LANES) {
                const Chunk c = chunk_at(&f, r, cx, dy);
                const int64_t s = (int64_t)gk * np + (int64_t)ly * stride + cx;
                i4 m = may_pass(&f, c) & ~i4_load(done + s);
                if (!any(m)) continue;
                f4 a = f4_splat(f.op) * exp_lanes(c.power);
                a = f4_sel(a > f4_splat(ALPHA_MAX), f4_splat(ALPHA_MAX), a);
                m &= ~(a < f4_splat(ALPHA_MIN));
                if (!any(m)) continue;
                const d4 Ts = d4_load(T + s);
                const d4 tn = Ts * (d4_splat(1.0) - d4_of(a));
                const i4 fin = m & narrow(tn < d4_splat(T_MIN)); /* group finished: not composited */
                if (any(fin)) {
                    i4_store(done + s, i4_load(done + s) | fin);
                    live -= count(fin);
                    live_g[gk] -= count(fin);
                    m &= ~fin;
                }
                const f4 w = f4_sel(m, a * f4_of(Ts), f4_splat(0.0f));
                for (int64_t ch = 0; ch < d; ++ch) {
                    float *ac = acc + ((int64_t)gk * d + ch) * np + (int64_t)ly * stride + cx;
                    const f4 old = f4_load(ac);
                    f4_store(ac, f4_sel(m, old + w * f4_splat(ck[ch]), old));
                }
                d4_store(T + s, d4_sel(wide(m), tn, Ts));
                i4_store(lst + s, i4_sel(m, index, i4_load(lst + s)));
                wsum += w;
            }
        }
        slot[pos] = f4_sum(wsum);
    }
    for (; pos < end; ++pos) slot[pos] = 0.0f; /* tile retired early */
}

/* Backward of one tile (see moegs_backward). Per (group, pixel), laid out as in forward_tile: T (the
 * transmittance, walked back from the final one), B (colour behind, channel-major), gi (the image
 * gradient, channel-major), gaTf (alpha gradient times the final transmittance), lst; all double
 * but lst. gcol: LANES * d doubles of scratch for the per-Gaussian colour sums. */
LANE_CLONES
static void backward_tile(Tile r, int G, int64_t d, int tile, const float *geo, const int32_t *box,
                          const int32_t *grp, const float *col, const int32_t *list, int64_t start,
                          int64_t end, int64_t stride_slot, float *slot, double *T,
                          double *B, const double *gi, const double *gaTf, const int32_t *lst,
                          const int32_t *maxlast_g, int32_t maxlast, double *gcol) {
    const int stride = lane_stride(tile);
    const int64_t np = (int64_t)tile * stride;
    memset(B, 0, (size_t)(G * d * np) * sizeof(double));
    /* Gaussians after the last contributor of every pixel get nothing from this tile */
    for (int64_t pos = start + maxlast + 1; pos < end; ++pos)
        memset(slot + pos * stride_slot, 0, (size_t)stride_slot * sizeof(float));
    for (int32_t j = maxlast; j >= 0; --j) {
        const int64_t pos = start + j;
        if (j >= PREFETCH_AHEAD) prefetch_gaussian(geo, box, grp, col, d, list[pos - PREFETCH_AHEAD]);
        const int32_t k = list[pos];
        const int32_t gk = grp[k];
        float *sl = slot + pos * stride_slot;
        if (j > maxlast_g[gk]) { /* behind the last contributor of all its group's pixels */
            memset(sl, 0, (size_t)stride_slot * sizeof(float));
            continue;
        }
        const Footprint f = footprint(geo, box, k, r);
        const float *ck = col + (int64_t)k * d;
        const d4 zero = d4_splat(0.0);
        d4 gmx = zero, gmy = zero, ga = zero, gb = zero, gc = zero, gop = zero;
        for (int64_t ch = 0; ch < d; ++ch) d4_store(gcol + LANES * ch, zero);
        const d4 ca = d4_splat(f.ca), cb = d4_splat(f.cb), cc = d4_splat(f.cc);
        for (int ly = f.ly0; ly <= f.ly1; ++ly) {
            const float dy = ((float)(r.y0 + ly) + 0.5f) - f.my;
            const d4 dyd = d4_splat((double)dy);
            for (int cx = f.lx0 / LANES * LANES; cx <= f.lx1; cx += LANES) {
                const Chunk c = chunk_at(&f, r, cx, dy);
                const int64_t s = (int64_t)gk * np + (int64_t)ly * stride + cx;
                i4 m = may_pass(&f, c) & ~(i4_load(lst + s) < j); /* not behind the last contributor */
                if (!any(m)) continue;
                const f4 e = exp_lanes(c.power);
                const f4 raw = f4_splat(f.op) * e;
                const i4 clamped = raw > f4_splat(ALPHA_MAX);
                const f4 a = f4_sel(clamped, f4_splat(ALPHA_MAX), raw);
                m &= ~(a < f4_splat(ALPHA_MIN));
                if (!any(m)) continue;
                /* lanes outside m get w = 0 and dp = 0, so they add nothing below */
                const l4 mw = wide(m);
                const d4 ad = d4_of(a);
                const d4 inv_om = d4_splat(1.0) / (d4_splat(1.0) - ad); /* a <= ALPHA_MAX: finite */
                const d4 Ts = d4_load(T + s);
                const d4 Tj = Ts * inv_om; /* transmittance in front of j */
                d4_store(T + s, d4_sel(mw, Tj, Ts));
                const d4 w = d4_sel(mw, ad * Tj, zero);
                d4 dot_c = zero, dot_b = zero;
                for (int64_t ch = 0; ch < d; ++ch) {
                    const int64_t o = ((int64_t)gk * d + ch) * np + (int64_t)ly * stride + cx;
                    const d4 gp = d4_load(gi + o);
                    const d4 cch = d4_splat((double)ck[ch]);
                    const d4 Bs = d4_load(B + o);
                    d4_store(gcol + LANES * ch, d4_load(gcol + LANES * ch) + w * gp);
                    dot_c += cch * gp;
                    dot_b += Bs * gp;
                    d4_store(B + o, Bs + w * cch);
                }
                const l4 live = wide(m & ~clamped); /* d alpha / d (opacity, power) = 0 when clamped */
                const d4 dal = Tj * dot_c + (d4_load(gaTf + s) - dot_b) * inv_om;
                const d4 dp = d4_sel(live, ad * dal, zero); /* dL/dpower */
                const d4 dxd = d4_of(c.dx);
                gop += d4_sel(live, d4_of(e) * dal, zero);
                ga += d4_splat(-0.5) * dxd * dxd * dp;
                gb += -dxd * dyd * dp;
                gc += d4_splat(-0.5) * dyd * dyd * dp;
                gmx += (ca * dxd + cb * dyd) * dp;
                gmy += (cb * dxd + cc * dyd) * dp;
            }
        }
        sl[0] = (float)d4_sum(gmx); sl[1] = (float)d4_sum(gmy);
        sl[2] = (float)d4_sum(ga); sl[3] = (float)d4_sum(gb); sl[4] = (float)d4_sum(gc);
        sl[5] = (float)d4_sum(gop);
        for (int64_t ch = 0; ch < d; ++ch) sl[6 + ch] = (float)d4_sum(d4_load(gcol + LANES * ch));
    }
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

#pragma omp parallel num_threads(nthreads)
    {
        /* thread-local per-(group, pixel) state of the current tile (forward_tile) */
        const int64_t np = (int64_t)tile * lane_stride(tile);
        double *T = (double *)malloc((size_t)(G * np) * sizeof(double));
        float *acc = (float *)malloc((size_t)(G * np * d) * sizeof(float));
        int32_t *lst = (int32_t *)malloc((size_t)(G * np) * sizeof(int32_t));
        int32_t *done = (int32_t *)malloc((size_t)(G * np) * sizeof(int32_t));
        int64_t *live_g = (int64_t *)malloc((size_t)G * sizeof(int64_t));
        const int ok = T && acc && lst && done && live_g;
        if (!ok) flag_error(&err);

#pragma omp for schedule(dynamic, 1)
        for (int64_t t = 0; t < ntiles; ++t) {
            if (!ok) continue;
            const Tile r = tile_at(t, ntx, tile, W, H);
            forward_tile(r, G, d, tile, geo, box, grp, col, list, tile_off[t], tile_off[t + 1], slot, T, acc,
                         lst, done, live_g);
            /* write the tile out */
            const int stride = lane_stride(tile);
            for (int gi = 0; gi < G; ++gi)
                for (int ly = 0; ly < r.h; ++ly)
                    for (int lx = 0; lx < r.w; ++lx) {
                        const int64_t s = (int64_t)gi * np + (int64_t)ly * stride + lx;
                        const int64_t o = ((int64_t)gi * H + r.y0 + ly) * W + r.x0 + lx;
                        const float *ac = acc + (int64_t)gi * d * np + (int64_t)ly * stride + lx;
                        for (int64_t c = 0; c < d; ++c) image[o * d + c] = ac[c * np];
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
    const int64_t stride_slot = 6 + d;
    float *slot = (float *)malloc((size_t)(total > 0 ? total : 1) * stride_slot * sizeof(float));
    if (!slot) return ERR_NOMEM;
    int err = 0;

#pragma omp parallel num_threads(nthreads)
    {
        /* thread-local per-(group, pixel) state of the current tile (backward_tile) */
        const int stride = lane_stride(tile);
        const int64_t np = (int64_t)tile * stride;
        double *T = (double *)malloc((size_t)(G * np) * sizeof(double));
        double *B = (double *)malloc((size_t)(G * np * d) * sizeof(double));
        double *gi = (double *)malloc((size_t)(G * np * d) * sizeof(double));
        double *gaTf = (double *)malloc((size_t)(G * np) * sizeof(double));
        int32_t *lst = (int32_t *)malloc((size_t)(G * np) * sizeof(int32_t));
        double *gcol = (double *)malloc((size_t)(LANES * d) * sizeof(double));
        int32_t *maxlast_g = (int32_t *)malloc((size_t)G * sizeof(int32_t));
        const int ok = T && B && gi && gaTf && lst && gcol && maxlast_g;
        if (!ok) flag_error(&err);

#pragma omp for schedule(dynamic, 1)
        for (int64_t t = 0; t < ntiles; ++t) {
            if (!ok) continue;
            const Tile r = tile_at(t, ntx, tile, W, H);
            /* load the per-pixel state of the tile (lanes outside the tile: neutral values, never used) */
            int32_t maxlast = -1;
            for (int64_t s = 0; s < G * np; ++s) { T[s] = 1.0; gaTf[s] = 0.0; lst[s] = -1; }
            memset(gi, 0, (size_t)(G * np * d) * sizeof(double));
            for (int g = 0; g < G; ++g) {
                maxlast_g[g] = -1;
                for (int ly = 0; ly < r.h; ++ly)
                    for (int lx = 0; lx < r.w; ++lx) {
                        const int64_t s = (int64_t)g * np + (int64_t)ly * stride + lx;
                        const int64_t o = ((int64_t)g * H + r.y0 + ly) * W + r.x0 + lx;
                        T[s] = tfinal[o];
                        gaTf[s] = (double)grad_alpha[o] * tfinal[o];
                        lst[s] = last[o];
                        if (last[o] > maxlast_g[g]) maxlast_g[g] = last[o];
                        for (int64_t c = 0; c < d; ++c)
                            gi[((int64_t)g * d + c) * np + (int64_t)ly * stride + lx] = grad_image[o * d + c];
                    }
                if (maxlast_g[g] > maxlast) maxlast = maxlast_g[g];
            }
            backward_tile(r, G, d, tile, geo, box, grp, col, list, tile_off[t], tile_off[t + 1], stride_slot,
                          slot, T, B, gi, gaTf, lst, maxlast_g, maxlast, gcol);
        }
        free(T); free(B); free(gi); free(gaTf); free(lst); free(gcol); free(maxlast_g);
    }
    if (err) { free(slot); return ERR_NOMEM; }

    /* reduce the pair slots per Gaussian in a fixed order and scatter to the original order */
#pragma omp parallel num_threads(nthreads) if (total > PAR_MIN)
    {
        double *acc = (double *)malloc((size_t)stride_slot * sizeof(double));
        if (!acc) flag_error(&err);
#pragma omp for schedule(static)
        for (int64_t k = 0; k < n; ++k) {
            if (!acc) continue;
            for (int64_t c = 0; c < stride_slot; ++c) acc[c] = 0.0;
            for (int64_t j = gstart[k]; j < gstart[k + 1]; ++j) {
                const float *sl = slot + pairpos[j] * stride_slot;
                for (int64_t c = 0; c < stride_slot; ++c) acc[c] += sl[c];
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
