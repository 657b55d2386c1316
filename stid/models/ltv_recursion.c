/* The time-varying recursion of stid.models.lpv, compiled ahead: the loop of its numba build
 * (stid/models/_ltv_numba.py), which stid/models/recursion.py takes where this one was not built.
 * Loaded through ctypes, it spares a cold command numba's import and cache load (0.18 s).
 *
 *   y[k]   = C(k) x + D(k) uo[k] + off(k)
 *   x[k+1] = F(k) x + G0(k) u[k] + G1(k) u[k+1]
 *
 * with every matrix interpolated linearly between grid nodes i and i+1 by the weight w[k]
 * (outputs) and w_s[k] (the step's midpoint speed). Arrays are C-ordered doubles (indices int64):
 * F (n_g, n_x, n_x), G0, G1 (n_g, n_x, n_u), C (n_g, n_y, n_x), D (n_g, n_y, n_u), off (n_g, n_y),
 * u, uo (n_t, n_u), x0 (n_x), y (n_t, n_y) written. Returns 0; -1 (y unfinished) where a grid
 * index lies outside the n_g nodes (a read beyond them would crash the process); -2 where the
 * state's few doubles could not be allocated. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* what recursion.py checks before it takes this library: a build of another layout is not used */
int64_t ltv_recursion_abi(void) { return 1; }

/* the loop; ``work`` holds 2 n_x doubles (the state and the next) */
static inline __attribute__((always_inline)) int64_t
kernel(const double *F, const double *G0, const double *G1, const double *C, const double *D, const double *off,
       const int64_t *idx, const double *w, const int64_t *idx_s, const double *w_s, const double *u,
       const double *uo, const double *x0, double *y, int64_t n_t, int64_t n_g, int64_t n_x, int64_t n_u,
       int64_t n_y, double *work)
{
    double *x = work, *xn = work + n_x;
    memcpy(x, x0, (size_t)n_x * sizeof(double));
    for (int64_t k = 0; k < n_t; k++) {
        int64_t i = idx[k];
        if (i < 0 || i > n_g - 2 || (k + 1 < n_t && (idx_s[k] < 0 || idx_s[k] > n_g - 2))) {
            return -1; /* a grid index outside the grid */
        }
        double a = w[k], b = 1.0 - a;
        for (int64_t o = 0; o < n_y; o++) {
            double acc = b * off[i * n_y + o] + a * off[(i + 1) * n_y + o];
            const double *c0 = C + (i * n_y + o) * n_x, *c1 = c0 + n_y * n_x;
            for (int64_t j = 0; j < n_x; j++)
                acc += (b * c0[j] + a * c1[j]) * x[j];
            const double *d0 = D + (i * n_y + o) * n_u, *d1 = d0 + n_y * n_u;
            for (int64_t j = 0; j < n_u; j++)
                acc += (b * d0[j] + a * d1[j]) * uo[k * n_u + j];
            y[k * n_y + o] = acc;
        }
        if (k + 1 < n_t) {
            i = idx_s[k];
            a = w_s[k];
            b = 1.0 - a;
            for (int64_t r = 0; r < n_x; r++) {
                double acc = 0.0;
                const double *f0 = F + (i * n_x + r) * n_x, *f1 = f0 + n_x * n_x;
                for (int64_t j = 0; j < n_x; j++)
                    acc += (b * f0[j] + a * f1[j]) * x[j];
                const double *g0 = G0 + (i * n_x + r) * n_u, *g0n = g0 + n_x * n_u;
                const double *g1 = G1 + (i * n_x + r) * n_u, *g1n = g1 + n_x * n_u;
                for (int64_t j = 0; j < n_u; j++) {
                    acc += (b * g0[j] + a * g0n[j]) * u[k * n_u + j];
                    acc += (b * g1[j] + a * g1n[j]) * u[(k + 1) * n_u + j];
                }
                xn[r] = acc;
            }
            memcpy(x, xn, (size_t)n_x * sizeof(double));
        }
    }
    return 0;
}

/* The kernel with its sizes as constants where they are the models' usual ones, else as they come:
 * with constant sizes the compiler unrolls the short sums (per sample, 4 states: 20 -> 11 ns; 5:
 * 41 -> 32 ns). The cases are the shapes a diagnosis simulates (steer in; ay and r out, or with the
 * slip angles for a nonlinear tyre's iteration; 4-9 states with the sensors' filters and effects;
 * the servo's lag alone). */
int64_t ltv_run(const double *F, const double *G0, const double *G1, const double *C, const double *D,
                const double *off, const int64_t *idx, const double *w, const int64_t *idx_s,
                const double *w_s, const double *u, const double *uo, const double *x0, double *y,
                int64_t n_t, int64_t n_g, int64_t n_x, int64_t n_u, int64_t n_y)
{
#define ARGS F, G0, G1, C, D, off, idx, w, idx_s, w_s, u, uo, x0, y, n_t, n_g
#define CASE(NX, NU, NY) \
    if (n_x == NX && n_u == NU && n_y == NY) { double work[2 * NX]; return kernel(ARGS, NX, NU, NY, work); }
    CASE(1, 1, 1) CASE(2, 1, 2) CASE(3, 1, 2) CASE(4, 1, 2) CASE(5, 1, 2) CASE(6, 1, 2) CASE(7, 1, 2) CASE(8, 1, 2)
    CASE(9, 1, 2) CASE(4, 2, 2) CASE(5, 2, 2) CASE(6, 2, 2) CASE(4, 3, 4) CASE(5, 3, 4) CASE(6, 3, 4)
#undef CASE
    double *work = malloc(2 * (size_t)(n_x > 0 ? n_x : 1) * sizeof(double));
    if (work == NULL)
        return -2;
    int64_t status = kernel(ARGS, n_x, n_u, n_y, work);
#undef ARGS
    free(work);
    return status;
}
