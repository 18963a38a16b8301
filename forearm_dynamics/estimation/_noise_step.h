/* What the noise estimator's compiled store (_noise_step.c) and its evaluations
 * (_noise_evaluations.c) share: the layouts of the arrays they are bound to and the Store.
 * One extension, two files: the store's per-sample bookkeeping and Python's type, and the
 * arithmetic of noise.py's three evaluations. */
#ifndef FOREARM_NOISE_STEP_H
#define FOREARM_NOISE_STEP_H
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "_buffers.h" /* get_vector, bound_call */

/* noise_store.Ctr, then noise_store.Rate, in their order (noise_step.bind compares FIELDS) */
enum { STARTED, ORIGIN, HAS_LAST, LAST_NS, LAST_D, SAME, COUNT, WCOUNT, VCOUNT, CAP, STRIDE,
       EVERY, WEVALS, VEVALS, PEVALS, IRREGULAR, N_CTR };
enum { DT, DT_AVG, STRIDE_DT, N_RATE };
#define FIELDS \
    "STARTED ORIGIN HAS_LAST LAST_NS LAST_D SAME COUNT WCOUNT VCOUNT CAP STRIDE EVERY WEVALS " \
    "VEVALS PEVALS IRREGULAR " \
    "DT DT_AVG STRIDE_DT"
#define NOT_STORED (-1)
#define N_BUFS 13
enum { B_CTR, B_RATE, B_RAW, B_RAWT, B_WRING, B_WT, B_VRING, B_VT, B_MSW, B_MSV, B_NCLIPV,
       B_MS, B_NCLIP };
#define BLOCKS 6 /* noise.py's ORDER + 1: the position difference's blocks */

typedef struct {
    PyObject_HEAD
    Py_buffer bufs[N_BUFS]; /* in the order of the B_ enum */
    int held; /* how many of bufs are held */
    Py_ssize_t n;
    double gap_periods, gap_min_s, rate_alpha, nominal_tol, new_rate, dense_period_s;
    long long dense_stride, same_ns;
    double tau_s, clip_sigmas;
    long long clip_run, min_evaluations;
    double window_stretch, block_spread_ratio;
    long long min_block;
    double *z; /* scratch: an evaluation's z (n), the position blocks' sums (BLOCKS n), a
                  block's squared stamp deviations (up to the ring's CAP) */
} Store;

/* Python's a % b for b > 0 (never negative) */
static inline long long pymod(long long a, long long b) {
    const long long m = a % b;
    return m < 0 ? m + b : m;
}

/* noise.py's evaluations, made due by the store (_noise_evaluations.c): c the counters, r the
 * periods, dense the white and velocity stride. position_evaluation returns 1 for an
 * evaluation it leaves to Python (nothing written). */
void white_evaluation(Store *self, int64_t *c, const double *r, long long dense);
void velocity_evaluation(Store *self, int64_t *c, long long dense);
int position_evaluation(Store *self, int64_t *c, const double *r);

#endif
