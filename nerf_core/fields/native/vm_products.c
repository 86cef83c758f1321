/* Fused CPU lookup of a TensoRF VM grid: bilinear plane taps times linear line taps, and its backward.
 *
 * The same numbers as ``TensorVMField._vm_reference`` (two ``F.grid_sample`` calls with
 * align_corners=True and zero padding, then a product), computed in one pass:
 *
 *   out[k, r, i] = bilerp(planes[k, r], col = u[i, A_k], row = u[i, B_k]) * lerp(lines[k, r], u[i, L_k])
 *
 * with plane k spanning axes (A_k, B_k) = (0,1), (0,2), (1,2) and its line along L_k = 2, 1, 0, and a
 * coordinate c in [-1, 1] mapped to (c + 1) / 2 * (N - 1) cells. Taps outside the grid weigh 0.
 *
 * Why it exists: on a CPU, grid_sample's backward (the gradient scatter into the planes) is parallel
 * over the batch dimension only, which is 3 here, and was 30-45 % of a vmgrid training step. This
 * backward is parallel over the R components instead, each slice of components owned by one thread, so
 * it needs no atomics and no per-thread copies; the corner indices and weights of each (plane, point)
 * are computed once in the forward and reused by every component and by the backward.
 *
 * Built at first use by ``nerf_core.utils.native`` (gcc/cc, no torch headers) and called through
 * ctypes, which releases the GIL. Threads are plain pthreads, one slice each.
 */
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <string.h>

static const int PLANE_A[3] = {0, 0, 1};
static const int PLANE_B[3] = {1, 2, 2};
static const int LINE_AXIS[3] = {2, 1, 0};

#define MAX_THREADS 256

/* One (plane, point) record: 4 plane taps and 2 line taps (flat indices into one N x N image and one
 * N line), with their weights; a tap outside the grid has index 0 and weight 0. */
typedef struct {
    int32_t p[4];
    float pw[4];
    int32_t l[2];
    float lw[2];
} Taps;

typedef struct {
    const float *planes, *lines, *u;
    float *out, *grad_planes, *grad_lines;
    const float *grad_out;
    Taps *taps;
    int64_t m, lo, hi; /* points [lo, hi) (forward) or (plane, component) pairs [lo, hi) of 3 R (backward) */
    int r, n;
} Job;

/* grid_sample's unnormalisation (align_corners=True) and its zero-padding bounds test. */
static inline float unnormalize(float c, int n) { return (c + 1.0f) / 2.0f * (float)(n - 1); }

static inline void tap1(float ix, int n, int32_t *idx, float *w) {
    float f = floorf(ix);
    int32_t i0 = (int32_t)f;
    float t = ix - f;
    int ok0 = (i0 >= 0 && i0 < n), ok1 = (i0 + 1 >= 0 && i0 + 1 < n);
    idx[0] = ok0 ? i0 : 0;
    w[0] = ok0 ? 1.0f - t : 0.0f;
    idx[1] = ok1 ? i0 + 1 : 0;
    w[1] = ok1 ? t : 0.0f;
}

static void make_taps(const float *u, int64_t i, int k, int n, Taps *t) {
    float ix = unnormalize(u[i * 3 + PLANE_A[k]], n);
    float iy = unnormalize(u[i * 3 + PLANE_B[k]], n);
    float ix0 = floorf(ix), iy0 = floorf(iy);
    int32_t x0 = (int32_t)ix0, y0 = (int32_t)iy0;
    float tx = ix - ix0, ty = iy - iy0;
    /* grid_sample's corner weights, in its order: nw, ne, sw, se. */
    float w[4] = {(1.0f - tx) * (1.0f - ty), tx * (1.0f - ty), (1.0f - tx) * ty, tx * ty};
    int32_t xs[4] = {x0, x0 + 1, x0, x0 + 1}, ys[4] = {y0, y0, y0 + 1, y0 + 1};
    for (int c = 0; c < 4; ++c) {
        int ok = xs[c] >= 0 && xs[c] < n && ys[c] >= 0 && ys[c] < n;
        t->p[c] = ok ? ys[c] * n + xs[c] : 0;
        t->pw[c] = ok ? w[c] : 0.0f;
    }
    /* The line is an (N, 1) image sampled at x = 0, so only its rows interpolate. */
    tap1(unnormalize(u[i * 3 + LINE_AXIS[k]], n), n, t->l, t->lw);
}

/* The planes and lines arrive channels-last, (3, N, N, R) and (3, N, R): one tap of all R components
 * is one contiguous run of R floats, so a point touches 4 + 2 short runs per plane instead of 6 R
 * scattered floats, and the loops over r vectorise. The output is point-major, (m, 3, R). */
static void *forward_slice(void *arg) {
    Job *j = (Job *)arg;
    const int R = j->r;
    const int64_t nn = (int64_t)j->n * j->n;
    for (int64_t i = j->lo; i < j->hi; ++i) {
        for (int k = 0; k < 3; ++k) {
            Taps *t = j->taps + (int64_t)k * j->m + i;
            make_taps(j->u, i, k, j->n, t);
            const float *P = j->planes + (int64_t)k * nn * R, *L = j->lines + (int64_t)k * j->n * R;
            const float *p0 = P + (int64_t)t->p[0] * R, *p1 = P + (int64_t)t->p[1] * R;
            const float *p2 = P + (int64_t)t->p[2] * R, *p3 = P + (int64_t)t->p[3] * R;
            const float *l0 = L + (int64_t)t->l[0] * R, *l1 = L + (int64_t)t->l[1] * R;
            const float w0 = t->pw[0], w1 = t->pw[1], w2 = t->pw[2], w3 = t->pw[3], v0 = t->lw[0], v1 = t->lw[1];
            float *o = j->out + (i * 3 + k) * R;
            for (int r = 0; r < R; ++r)
                o[r] = (w0 * p0[r] + w1 * p1[r] + w2 * p2[r] + w3 * p3[r]) * (v0 * l0[r] + v1 * l1[r]);
        }
    }
    return 0;
}

/* A backward slice owns a run [lo, hi) of the 3 R (plane, component) pairs, plane-major: it alone writes
 * those gradient entries, so no two threads ever add to the same float, and two threads share a plane
 * only at the seam between their runs. */
static void *backward_slice(void *arg) {
    Job *j = (Job *)arg;
    const int R = j->r;
    const int64_t nn = (int64_t)j->n * j->n;
    for (int k = 0; k < 3; ++k) {
        int64_t a = j->lo - (int64_t)k * R, b = j->hi - (int64_t)k * R;
        if (a < 0) a = 0;
        if (b > R) b = R;
        if (a >= b) continue;
        const int ra = (int)a, rb = (int)b;
        const Taps *tk = j->taps + (int64_t)k * j->m;
        const float *P = j->planes + (int64_t)k * nn * R, *L = j->lines + (int64_t)k * j->n * R;
        float *gP = j->grad_planes ? j->grad_planes + (int64_t)k * nn * R : 0;
        float *gL = j->grad_lines ? j->grad_lines + (int64_t)k * j->n * R : 0;
        for (int64_t i = 0; i < j->m; ++i) {
            const Taps *t = tk + i;
            const float *g = j->grad_out + (i * 3 + k) * R;
            int any = 0;
            for (int r = ra; r < rb; ++r) any |= g[r] != 0.0f;
            if (!any) continue; /* samples whose colour was not used add nothing */
            const int64_t q0 = (int64_t)t->p[0] * R, q1 = (int64_t)t->p[1] * R, q2 = (int64_t)t->p[2] * R,
                          q3 = (int64_t)t->p[3] * R, s0 = (int64_t)t->l[0] * R, s1 = (int64_t)t->l[1] * R;
            const float w0 = t->pw[0], w1 = t->pw[1], w2 = t->pw[2], w3 = t->pw[3], v0 = t->lw[0], v1 = t->lw[1];
            if (gP) {
                for (int r = ra; r < rb; ++r) {
                    const float gl = g[r] * (v0 * L[s0 + r] + v1 * L[s1 + r]);
                    gP[q0 + r] += w0 * gl;
                    gP[q1 + r] += w1 * gl;
                    gP[q2 + r] += w2 * gl;
                    gP[q3 + r] += w3 * gl;
                }
            }
            if (gL) {
                for (int r = ra; r < rb; ++r) {
                    const float gp = g[r] * (w0 * P[q0 + r] + w1 * P[q1 + r] + w2 * P[q2 + r] + w3 * P[q3 + r]);
                    gL[s0 + r] += v0 * gp;
                    gL[s1 + r] += v1 * gp;
                }
            }
        }
    }
    return 0;
}

/* Run fn over [0, total) split into `threads` slices (the calling thread takes the first). */
static int run_sliced(void *(*fn)(void *), Job *proto, int64_t total, int threads) {
    if (threads < 1) threads = 1;
    if (threads > MAX_THREADS) threads = MAX_THREADS;
    if (threads > total) threads = total > 0 ? (int)total : 1;
    Job jobs[MAX_THREADS];
    pthread_t ids[MAX_THREADS];
    int started[MAX_THREADS];
    for (int t = 0; t < threads; ++t) {
        jobs[t] = *proto;
        jobs[t].lo = total * t / threads;
        jobs[t].hi = total * (t + 1) / threads;
        started[t] = 0;
    }
    for (int t = 1; t < threads; ++t) started[t] = pthread_create(&ids[t], 0, fn, &jobs[t]) == 0;
    fn(&jobs[0]);
    for (int t = 1; t < threads; ++t) {
        if (started[t]) pthread_join(ids[t], 0);
        else fn(&jobs[t]); /* no thread could be made: do its slice here */
    }
    return 0;
}

/* planes (3, N, N, R), lines (3, N, R), u (m, 3) -> out (m, 3, R); taps (3, m) is written for backward. */
int vm_products_forward(const float *planes, const float *lines, const float *u, int64_t m, int r, int n,
                        float *out, void *taps, int threads) {
    Job j;
    memset(&j, 0, sizeof j);
    j.planes = planes, j.lines = lines, j.u = u, j.out = out, j.taps = (Taps *)taps, j.m = m, j.r = r, j.n = n;
    return run_sliced(forward_slice, &j, m, threads);
}

/* grad_out (m, 3, R) -> grad_planes (3, N, N, R) and grad_lines (3, N, R), both zeroed by the caller;
 * either may be NULL when that gradient is not needed. */
int vm_products_backward(const float *planes, const float *lines, const void *taps, int64_t m, int r, int n,
                         const float *grad_out, float *grad_planes, float *grad_lines, int threads) {
    Job j;
    memset(&j, 0, sizeof j);
    j.planes = planes, j.lines = lines, j.taps = (Taps *)taps, j.m = m, j.r = r, j.n = n;
    j.grad_out = grad_out, j.grad_planes = grad_planes, j.grad_lines = grad_lines;
    return run_sliced(backward_slice, &j, (int64_t)3 * r, threads);
}

/* Bytes of one tap record, so that the caller allocates 3 m of them. */
int vm_products_taps_bytes(void) { return (int)sizeof(Taps); }
