/*
 * moegs CPU multiresolution hash encoding: forward and the gradient w.r.t. the tables.
 *
 * Plain C99 + OpenMP, loaded with ctypes (no torch or Python headers). The contract is that of
 * moegs/fields/hashgrid.py (HashGrid._encode_reference, the test oracle), evaluated with the same
 * float32 operations in the same order:
 *   - a point with any coordinate outside [0, 1] (or NaN) gets zero features and no gradient;
 *   - pos = u * scale[l, d]; cell = floor(pos); f = pos - cell; w_hi = f * f * (3 - 2 f);
 *   - corner k (bit d of k = upper vertex along d) has weight prod_d (bit ? w_hi : 1 - w_hi), the
 *     product taken in increasing d, and row offset[l] + index(cell + bits) where index is the dense
 *     index sum_d c_d stride[l, d] or the hash XOR_d (c_d p_d mod 2^32), either way mod size[l];
 *   - out[n, l, :] = sum over corners k = 0, 1, ... (in that order) of weight_k table[row_k, :].
 *
 * The forward is parallel over points, the backward over levels (the table rows of two levels are
 * disjoint), each level's gradient summed over points in increasing order: deterministic and
 * bit-identical for any thread count.
 */

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "moegs_api.h"

#define HG_MAX_DIM 3
#define HG_PAR_MIN 4096 /* points below which the forward runs on the calling thread */

static const uint64_t HG_PRIMES[HG_MAX_DIM] = {1u, 2654435761u, 805459861u};

/* Per-level constants, flattened: scales [L, D] float, strides [L, D] int64, sizes [L] int64,
 * offsets [L] int64 (first row of the level), dense [L] uint8. */
typedef struct {
    int dim, levels, feat;
    const float *scales;
    const int64_t *strides, *sizes, *offsets;
    const uint8_t *dense;
} hg_grid;

static int hg_inside(const float *u, int dim) {
    for (int d = 0; d < dim; d++)
        if (!(u[d] >= 0.0f && u[d] <= 1.0f)) return 0;
    return 1;
}

static int hg_has_nan(const float *u, int dim) {
    for (int d = 0; d < dim; d++)
        if (isnan(u[d])) return 1;
    return 0;
}

/* The 2^D corners of point u's cell at level l: weights w[k] and table rows row[k]. */
static void hg_corners(const hg_grid *g, const float *u, int l, float *w, int64_t *row) {
    float wd[HG_MAX_DIM][2];
    int64_t key[HG_MAX_DIM][2];
    const int dense = g->dense[l];
    for (int d = 0; d < g->dim; d++) {
        const float pos = u[d] * g->scales[l * g->dim + d];
        const float c = floorf(pos);
        const float f = pos - c;
        const float hi = f * f * (3.0f - 2.0f * f);
        wd[d][0] = 1.0f - hi;
        wd[d][1] = hi;
        for (int b = 0; b < 2; b++) {
            const int64_t v = (int64_t)c + b;
            key[d][b] = dense ? v * g->strides[l * g->dim + d] : (int64_t)(((uint64_t)v * HG_PRIMES[d]) & 0xFFFFFFFFu);
        }
    }
    const int64_t size = g->sizes[l], offset = g->offsets[l];
    const int pow2 = (size & (size - 1)) == 0;
    for (int k = 0; k < (1 << g->dim); k++) {
        float wk = 1.0f;
        int64_t index = 0;
        for (int d = 0; d < g->dim; d++) {
            const int bit = (k >> d) & 1;
            wk = wk * wd[d][bit];
            index = dense ? index + key[d][bit] : index ^ key[d][bit];
        }
        /* index mod size without a division in the common cases (in range, power of two) */
        w[k] = wk;
        row[k] = offset + (index < size ? index : pow2 ? index & (size - 1) : index % size);
    }
}

MOEGS_API int moegs_hashgrid_forward(int64_t n, int dim, int levels, int feat, int nthreads, const float *scales,
                                     const int64_t *strides, const int64_t *sizes, const int64_t *offsets,
                                     const uint8_t *dense, const float *u, const float *table, float *out) {
    if (n < 0 || dim < 1 || dim > HG_MAX_DIM || levels < 1 || feat < 1) return -3;
    if (nthreads < 1) nthreads = 1;
    const hg_grid g = {dim, levels, feat, scales, strides, sizes, offsets, dense};
    const int corners = 1 << dim;
#pragma omp parallel for num_threads(nthreads) schedule(static) if (n >= HG_PAR_MIN)
    for (int64_t i = 0; i < n; i++) {
        const float *ui = u + i * dim;
        float *oi = out + i * (int64_t)levels * feat;
        if (!hg_inside(ui, dim)) { /* zero features; NaN where a coordinate is NaN, as the reference */
            const float fill = hg_has_nan(ui, dim) ? NAN : 0.0f;
            for (int64_t j = 0; j < (int64_t)levels * feat; j++) oi[j] = fill;
            continue;
        }
        for (int l = 0; l < levels; l++) {
            float w[1 << HG_MAX_DIM];
            int64_t row[1 << HG_MAX_DIM];
            hg_corners(&g, ui, l, w, row);
            float *o = oi + (int64_t)l * feat;
            for (int f = 0; f < feat; f++) o[f] = w[0] * table[row[0] * feat + f];
            for (int k = 1; k < corners; k++)
                for (int f = 0; f < feat; f++) o[f] = o[f] + w[k] * table[row[k] * feat + f];
        }
    }
    return 0;
}

/* grad_table must be zero on entry; it receives sum over points of weight_k * grad_out. */
MOEGS_API int moegs_hashgrid_backward(int64_t n, int dim, int levels, int feat, int nthreads, const float *scales,
                                      const int64_t *strides, const int64_t *sizes, const int64_t *offsets,
                                      const uint8_t *dense, const float *u, const float *grad_out,
                                      float *grad_table) {
    if (n < 0 || dim < 1 || dim > HG_MAX_DIM || levels < 1 || feat < 1) return -3;
    if (nthreads < 1) nthreads = 1;
    const hg_grid g = {dim, levels, feat, scales, strides, sizes, offsets, dense};
    const int corners = 1 << dim;
#pragma omp parallel for num_threads(nthreads) schedule(dynamic, 1) if (n * levels >= HG_PAR_MIN)
    for (int l = 0; l < levels; l++) {
        for (int64_t i = 0; i < n; i++) {
            const float *ui = u + i * dim;
            if (!hg_inside(ui, dim)) continue;
            float w[1 << HG_MAX_DIM];
            int64_t row[1 << HG_MAX_DIM];
            hg_corners(&g, ui, l, w, row);
            const float *go = grad_out + (i * levels + l) * feat;
            for (int k = 0; k < corners; k++)
                for (int f = 0; f < feat; f++) grad_table[row[k] * feat + f] += w[k] * go[f];
        }
    }
    return 0;
}
