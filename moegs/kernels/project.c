/*
 * moegs CPU EWA projection: forward and analytic backward of moegs/render/projection.py's `project`
 * (its torch reference and test oracle), for float32 inputs.
 *
 * Plain C99 + OpenMP, no torch headers (loaded with ctypes like raster.c). Built with
 * -ffp-contract=off and without -ffast-math: the forward performs the reference's float32 operations
 * one by one in the reference's order (camera_points, _covariance_2d, project), so its outputs, radii
 * included, equal the reference's to the bit. Two torch spellings matter here: `scalar / tensor` is
 * `reciprocal(tensor) * scalar`, and a Python float meeting a float32 tensor is rounded to float32
 * first. The backward is the chain rule of that graph, in double, rounded to float32 at the end.
 *
 * Camera record `cam` (float32, 21 values): world-to-camera rotation R (row-major, 9), translation t
 * (3), fx, fy, cx, cy, the Jacobian clamp (u_min, u_max, v_min, v_max) and eps2d.
 */

#include <math.h>
#include <stdint.h>

#include "moegs_api.h"

#define CAM_R 0
#define CAM_T 9
#define CAM_FX 12
#define CAM_FY 13
#define CAM_CX 14
#define CAM_CY 15
#define CAM_LIMITS 16
#define CAM_EPS2D 20

#define RADIUS_SIGMAS 3.0f
#define EIGEN_GAP_FLOOR 0.1f
#define MAX_RADIUS 1073741824.0f /* 2**30 */
#define PAR_MIN_PROJECT 4096

/* Everything the forward computes for one Gaussian that the backward needs again. */
typedef struct {
    float p[3], depth, u_raw, v_raw, u, v;
    float j00, j02, j11, j12;
    float t0[3], t1[3], p0[3], p1[3];
    float xx, xy, yy, a, b, c, det, safe_det, raw_det, ratio;
    int in_depth, valid, positive;
} Projected;

static inline float clampf(float x, float lo, float hi) {
    /* torch.clamp: NaN stays NaN */
    if (x < lo) return lo;
    if (x > hi) return hi;
    return x;
}

static void project_one(const float *mean, const float *S, const float *cam, float near, float far,
                        int antialiased, Projected *q) {
    const float *R = cam + CAM_R, *t = cam + CAM_T;
    const float fx = cam[CAM_FX], fy = cam[CAM_FY];
    for (int i = 0; i < 3; ++i)
        q->p[i] = ((mean[0] * R[3 * i] + mean[1] * R[3 * i + 1]) + mean[2] * R[3 * i + 2]) + t[i];
    const float z = q->p[2];
    q->in_depth = (z > near) && (z < far);
    q->depth = q->in_depth ? z : 1.0f;
    q->u_raw = q->p[0] / q->depth;
    q->v_raw = q->p[1] / q->depth;
    q->u = clampf(q->u_raw, cam[CAM_LIMITS], cam[CAM_LIMITS + 1]);
    q->v = clampf(q->v_raw, cam[CAM_LIMITS + 2], cam[CAM_LIMITS + 3]);
    const float inv_depth = 1.0f / q->depth;
    q->j00 = inv_depth * fx;
    q->j02 = (-fx * q->u) / q->depth;
    q->j11 = inv_depth * fy;
    q->j12 = (-fy * q->v) / q->depth;
    for (int k = 0; k < 3; ++k) {
        q->t0[k] = q->j00 * R[k] + q->j02 * R[6 + k];
        q->t1[k] = q->j11 * R[3 + k] + q->j12 * R[6 + k];
    }
    for (int k = 0; k < 3; ++k) {
        q->p0[k] = (q->t0[0] * S[k] + q->t0[1] * S[3 + k]) + q->t0[2] * S[6 + k];
        q->p1[k] = (q->t1[0] * S[k] + q->t1[1] * S[3 + k]) + q->t1[2] * S[6 + k];
    }
    q->xx = (q->p0[0] * q->t0[0] + q->p0[1] * q->t0[1]) + q->p0[2] * q->t0[2];
    q->xy = (q->p0[0] * q->t1[0] + q->p0[1] * q->t1[1]) + q->p0[2] * q->t1[2];
    q->yy = (q->p1[0] * q->t1[0] + q->p1[1] * q->t1[1]) + q->p1[2] * q->t1[2];
    const float eps2d = cam[CAM_EPS2D];
    q->a = q->xx + eps2d;
    q->c = q->yy + eps2d;
    q->b = q->xy;
    q->det = q->a * q->c - q->b * q->b;
    q->valid = q->in_depth && isfinite(q->det) && q->det > 0.0f;
    q->safe_det = q->valid ? q->det : 1.0f;
    q->raw_det = q->xx * q->yy - q->b * q->b;
    q->positive = antialiased && q->valid && q->raw_det > 0.0f;
    q->ratio = q->positive ? q->raw_det / q->safe_det : 1.0f;
}

/*
 * Forward. means [n,3], covars [n,3,3], opac [n] float32 -> means2d [n,2], conics [n,3],
 * opac_out [n] (times the antialiasing compensation when `antialiased`), depths [n] (camera z),
 * radii [n] int32 (0 = culled). Returns 0.
 */
MOEGS_API int moegs_project_forward(int64_t n, int32_t nthreads, const float *means, const float *covars,
                                    const float *opac, const float *cam, int32_t width, int32_t height,
                                    float near, float far, int32_t antialiased, float *means2d,
                                    float *conics, float *opac_out, float *depths, int32_t *radii) {
    if (nthreads < 1) nthreads = 1;
#pragma omp parallel for num_threads(nthreads) schedule(static) if (n > PAR_MIN_PROJECT)
    for (int64_t i = 0; i < n; ++i) {
        Projected q;
        project_one(means + 3 * i, covars + 9 * i, cam, near, far, antialiased, &q);
        const float mx = (cam[CAM_FX] * q.p[0]) / q.depth + cam[CAM_CX];
        const float my = (cam[CAM_FY] * q.p[1]) / q.depth + cam[CAM_CY];
        means2d[2 * i] = mx;
        means2d[2 * i + 1] = my;
        depths[i] = q.p[2];
        float *con = conics + 3 * i;
        if (q.valid) {
            con[0] = q.c / q.safe_det; con[1] = -q.b / q.safe_det; con[2] = q.a / q.safe_det;
        } else {
            con[0] = con[1] = con[2] = 0.0f;
        }
        opac_out[i] = antialiased ? opac[i] * (q.positive ? sqrtf(q.ratio) : 0.0f) : opac[i];
        float radius = 0.0f;
        if (q.valid) {
            const float mid = 0.5f * (q.a + q.c);
            float gap = mid * mid - q.safe_det;
            if (!(gap >= EIGEN_GAP_FLOOR)) gap = isnan(gap) ? gap : EIGEN_GAP_FLOOR; /* torch.clamp(min) */
            radius = ceilf(RADIUS_SIGMAS * sqrtf(mid + sqrtf(gap)));
            if (radius > MAX_RADIUS) radius = MAX_RADIUS;
        }
        const int on_screen = (mx + radius > 0.0f) && (mx - radius < (float)width) && (my + radius > 0.0f) &&
                              (my - radius < (float)height);
        radii[i] = (q.valid && on_screen) ? (int32_t)radius : 0;
    }
    return 0;
}

/*
 * Backward: the gradients of means2d, conics, opac_out and depths -> those of means [n,3],
 * covars [n,3,3] (all nine entries, as the reference reads them) and opac [n]. Returns 0.
 */
MOEGS_API int moegs_project_backward(int64_t n, int32_t nthreads, const float *means, const float *covars,
                                     const float *opac, const float *cam, float near, float far,
                                     int32_t antialiased, const float *g_means2d, const float *g_conics,
                                     const float *g_opac_out, const float *g_depths, float *g_means,
                                     float *g_covars, float *g_opac) {
    if (nthreads < 1) nthreads = 1;
#pragma omp parallel for num_threads(nthreads) schedule(static) if (n > PAR_MIN_PROJECT)
    for (int64_t i = 0; i < n; ++i) {
        Projected q;
        const float *S = covars + 9 * i;
        project_one(means + 3 * i, S, cam, near, far, antialiased, &q);
        const double fx = cam[CAM_FX], fy = cam[CAM_FY], depth = q.depth, d2 = depth * depth;
        const double go = g_opac_out[i];

        /* opacity (and the antialiasing compensation) */
        double g_xx = 0.0, g_yy = 0.0, g_b = 0.0, g_a = 0.0, g_c = 0.0, g_sd = 0.0;
        if (!antialiased) {
            g_opac[i] = (float)go;
        } else if (q.positive) {
            const double sq = sqrt((double)q.ratio);
            g_opac[i] = (float)(go * sq);
            const double g_ratio = go * opac[i] * 0.5 / sq;
            const double g_rd = g_ratio / q.safe_det;
            g_sd -= g_ratio * q.raw_det / ((double)q.safe_det * q.safe_det);
            g_xx += g_rd * q.yy;
            g_yy += g_rd * q.xx;
            g_b -= 2.0 * q.b * g_rd;
        } else {
            g_opac[i] = 0.0f;
        }

        /* conics = (c, -b, a) / det where valid */
        if (q.valid) {
            const double sd = q.safe_det, g0 = g_conics[3 * i], g1 = g_conics[3 * i + 1], g2 = g_conics[3 * i + 2];
            g_c += g0 / sd;
            g_b -= g1 / sd;
            g_a += g2 / sd;
            g_sd += (-g0 * q.c + g1 * q.b - g2 * q.a) / (sd * sd);
            /* safe_det = det where valid; det = a c - b^2 */
            g_a += g_sd * q.c;
            g_c += g_sd * q.a;
            g_b -= 2.0 * q.b * g_sd;
        }
        g_xx += g_a;
        g_yy += g_c;
        const double g_xy = g_b;

        /* xx = p0 . t0, xy = p0 . t1, yy = p1 . t1; p0 = t0 S, p1 = t1 S */
        double g_p0[3], g_p1[3], g_t0[3], g_t1[3];
        for (int k = 0; k < 3; ++k) {
            g_p0[k] = g_xx * q.t0[k] + g_xy * q.t1[k];
            g_p1[k] = g_yy * q.t1[k];
            g_t0[k] = g_xx * q.p0[k];
            g_t1[k] = g_xy * q.p0[k] + g_yy * q.p1[k];
        }
        float *gS = g_covars + 9 * i;
        for (int m = 0; m < 3; ++m) {
            for (int k = 0; k < 3; ++k) {
                g_t0[m] += g_p0[k] * S[3 * m + k];
                g_t1[m] += g_p1[k] * S[3 * m + k];
            }
        }
        for (int m = 0; m < 3; ++m)
            for (int k = 0; k < 3; ++k) gS[3 * m + k] = (float)(g_p0[k] * q.t0[m] + g_p1[k] * q.t1[m]);

        /* t0 = j00 R0 + j02 R2, t1 = j11 R1 + j12 R2 */
        const float *R = cam + CAM_R;
        double g_j00 = 0.0, g_j02 = 0.0, g_j11 = 0.0, g_j12 = 0.0;
        for (int k = 0; k < 3; ++k) {
            g_j00 += g_t0[k] * R[k];
            g_j02 += g_t0[k] * R[6 + k];
            g_j11 += g_t1[k] * R[3 + k];
            g_j12 += g_t1[k] * R[6 + k];
        }
        /* j00 = fx / depth, j02 = -fx u / depth, j11 = fy / depth, j12 = -fy v / depth */
        double g_depth = -(g_j00 * fx + g_j11 * fy) / d2 + (g_j02 * fx * q.u + g_j12 * fy * q.v) / d2;
        const double g_u = -g_j02 * fx / depth, g_v = -g_j12 * fy / depth;
        /* u = clamp(p0 / depth) passes the gradient inside [min, max] (torch.clamp) */
        const float *lim = cam + CAM_LIMITS;
        const double g_ur = (q.u_raw >= lim[0] && q.u_raw <= lim[1]) ? g_u : 0.0;
        const double g_vr = (q.v_raw >= lim[2] && q.v_raw <= lim[3]) ? g_v : 0.0;
        double g_p[3];
        g_p[0] = g_ur / depth;
        g_p[1] = g_vr / depth;
        g_depth -= (g_ur * q.p[0] + g_vr * q.p[1]) / d2;
        /* means2d = (f p / depth) + c */
        const double gx = g_means2d[2 * i], gy = g_means2d[2 * i + 1];
        g_p[0] += gx * fx / depth;
        g_p[1] += gy * fy / depth;
        g_depth -= (gx * fx * q.p[0] + gy * fy * q.p[1]) / d2;
        /* depth = z where in range; depths = z */
        g_p[2] = (q.in_depth ? g_depth : 0.0) + g_depths[i];
        /* p = R mean + t */
        for (int j = 0; j < 3; ++j)
            g_means[3 * i + j] = (float)(g_p[0] * R[j] + g_p[1] * R[3 + j] + g_p[2] * R[6 + j]);
    }
    return 0;
}

/*
 * World-space covariances R S S^T R^T from quaternions (w, x, y, z, used as given: not normalised) and
 * scales, as moegs/render/projection.py's covariance_3d computes them in float32: R from the
 * quaternion's products, M = R diag(s), covariance entry (i, j) = ((M_i0 M_j0 + M_i1 M_j1) + M_i2 M_j2).
 */
static void rotation(const float *q, float *R) {
    const float w = q[0], x = q[1], y = q[2], z = q[3];
    R[0] = 1.0f - 2.0f * (y * y + z * z);
    R[1] = 2.0f * (x * y - w * z);
    R[2] = 2.0f * (x * z + w * y);
    R[3] = 2.0f * (x * y + w * z);
    R[4] = 1.0f - 2.0f * (x * x + z * z);
    R[5] = 2.0f * (y * z - w * x);
    R[6] = 2.0f * (x * z - w * y);
    R[7] = 2.0f * (y * z + w * x);
    R[8] = 1.0f - 2.0f * (x * x + y * y);
}

/* quats [n,4], scales [n,3] float32 -> covars [n,3,3]. Returns 0. */
MOEGS_API int moegs_covariance_forward(int64_t n, int32_t nthreads, const float *quats, const float *scales,
                                       float *covars) {
    if (nthreads < 1) nthreads = 1;
#pragma omp parallel for num_threads(nthreads) schedule(static) if (n > PAR_MIN_PROJECT)
    for (int64_t i = 0; i < n; ++i) {
        float R[9], M[9];
        rotation(quats + 4 * i, R);
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) M[3 * r + c] = R[3 * r + c] * scales[3 * i + c];
        float *S = covars + 9 * i;
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c)
                S[3 * r + c] = (M[3 * r] * M[3 * c] + M[3 * r + 1] * M[3 * c + 1]) + M[3 * r + 2] * M[3 * c + 2];
    }
    return 0;
}

/* The gradient of covars [n,3,3] (all nine entries) -> those of quats [n,4] and scales [n,3], in double.
 * With G the gradient of S = M M^T: dM = (G + G^T) M; M = R diag(s). Returns 0. */
MOEGS_API int moegs_covariance_backward(int64_t n, int32_t nthreads, const float *quats, const float *scales,
                                        const float *g_covars, float *g_quats, float *g_scales) {
    if (nthreads < 1) nthreads = 1;
#pragma omp parallel for num_threads(nthreads) schedule(static) if (n > PAR_MIN_PROJECT)
    for (int64_t i = 0; i < n; ++i) {
        float R[9];
        const float *q = quats + 4 * i, *s = scales + 3 * i, *G = g_covars + 9 * i;
        rotation(q, R);
        double M[9], gM[9], gR[9];
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) M[3 * r + c] = (double)R[3 * r + c] * s[c];
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) {
                double sum = 0.0;
                for (int k = 0; k < 3; ++k) sum += ((double)G[3 * r + k] + G[3 * k + r]) * M[3 * k + c];
                gM[3 * r + c] = sum;
            }
        for (int c = 0; c < 3; ++c) {
            double gs = 0.0;
            for (int r = 0; r < 3; ++r) {
                gR[3 * r + c] = gM[3 * r + c] * s[c];
                gs += gM[3 * r + c] * R[3 * r + c];
            }
            g_scales[3 * i + c] = (float)gs;
        }
        const double w = q[0], x = q[1], y = q[2], z = q[3];
        /* d R / d (w, x, y, z), entry by entry (rotation above) */
        const double gw = 2.0 * (-z * gR[1] + y * gR[2] + z * gR[3] - x * gR[5] - y * gR[6] + x * gR[7]);
        const double gx = 2.0 * (y * gR[1] + z * gR[2] + y * gR[3] - 2.0 * x * gR[4] - w * gR[5] + z * gR[6] +
                                 w * gR[7] - 2.0 * x * gR[8]);
        const double gy = 2.0 * (-2.0 * y * gR[0] + x * gR[1] + w * gR[2] + x * gR[3] + z * gR[5] - w * gR[6] +
                                 z * gR[7] - 2.0 * y * gR[8]);
        const double gz = 2.0 * (-2.0 * z * gR[0] - w * gR[1] + x * gR[2] + w * gR[3] - 2.0 * z * gR[4] +
                                 y * gR[5] + x * gR[6] + y * gR[7]);
        g_quats[4 * i] = (float)gw;
        g_quats[4 * i + 1] = (float)gx;
        g_quats[4 * i + 2] = (float)gy;
        g_quats[4 * i + 3] = (float)gz;
    }
    return 0;
}
