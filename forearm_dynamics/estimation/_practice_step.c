/* The practice filter's per-sample arithmetic in two calls (practice_step.py says why).
 *
 * Practice(ring, w, last, fout, fctr, dis, wq, wx, ker, ref, s, share, wctr, bctr, pfw, target,
 * use, qdd, params) binds the arrays of practice_fir.PracticeFIR (ring (2 (K + 1), n), w (K,),
 * last, fout (n,), fctr int64 [count, t_ns]), of practice_blend.PracticeBlend and its window
 * (dis (n,), wq (2 (2 h + 1), n), wx (h + 1, 2, n), ker (2 h + 1,), ref (n,), s (6, n),
 * share (n,), wctr int64 [count], bctr int64 [evaluations]) and of practice_output.py (pfw,
 * target (n,), use (n,) bool, qdd (n,): the output's q̈ row); all C-contiguous, writable but
 * w and ker, held (a buffer of each) while the Practice lives; params = (K, h, every, dt, sum, fast,
 * alpha, share, fade_s): the FIR's taps and nominal period and its taps' sum, the window's
 * half width and evaluation stride, the blend's rates, practice_filter and FADE_S.
 *   push(t_ns, q) -> None: PracticeFIR.push (the dropped samples on the line, then q).
 *   output(dt, q) -> None: practice_output._practice_filter_output once the FIR is
 *       configured: the filter's q̈ (PracticeFIR.estimate), PracticeBlend.add, the fade and
 *       the blend into qdd; dt the last step (the fade's), q the sample's positions.
 * Python's operations in Python's order, built without fused multiply-add; the two sums numpy
 * hands to BLAS (the FIR's taps, the practice's kernel) are summed here in order, so those
 * two round differently (test_practice_step.py bounds the difference over whole streams).
 */
#include "_kalman_step.h"

#include <math.h>
#include <string.h>

enum { P_RING, P_W, P_LAST, P_FOUT, P_FCTR, P_DIS, P_WQ, P_WX, P_KER, P_REF, P_S, P_SHARE,
       P_WCTR, P_BCTR, P_PFW, P_TARGET, P_USE, P_QDD, N_PB };
enum { F_COUNT, F_T_NS };

typedef struct {
    PyObject_HEAD
    Py_buffer bufs[N_PB]; /* in the order of the P_ enum */
    int held;             /* how many of bufs are held */
    Py_ssize_t n, K, h, every;
    double dt, sum, fast, alpha, share, fade_s;
} Practice;

static void release_all(Practice *self) {
    for (int i = 0; i < self->held; i++)
        PyBuffer_Release(&self->bufs[i]);
    self->held = 0;
}

static void Practice_dealloc(Practice *self) {
    release_all(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

#define BUF(i) ((double *)self->bufs[i].buf)
#define CTR(i) ((int64_t *)self->bufs[i].buf)

static int Practice_init(Practice *self, PyObject *args, PyObject *kwds) {
    static char *names[] = {"ring", "w", "last", "fout", "fctr", "dis", "wq", "wx", "ker", "ref",
                            "s", "share", "wctr", "bctr", "pfw", "target", "use", "qdd", "params",
                            NULL};
    PyObject *arr[N_PB], *params;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOOOOOOOOOOOOOOOOOO", names, &arr[0], &arr[1],
                                     &arr[2], &arr[3], &arr[4], &arr[5], &arr[6], &arr[7],
                                     &arr[8], &arr[9], &arr[10], &arr[11], &arr[12], &arr[13],
                                     &arr[14], &arr[15], &arr[16], &arr[17], &params))
        return -1;
    release_all(self);
    if (!PyArg_ParseTuple(params, "nnndddddd", &self->K, &self->h, &self->every, &self->dt,
                          &self->sum, &self->fast, &self->alpha, &self->share, &self->fade_s))
        return -1;
    if (self->K < 1 || self->h < 1 || self->every < 1 || !(self->dt > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "params: K, h and every at least 1, dt > 0");
        return -1;
    }
    Py_buffer *fout = NULL;
    for (int i = 0; i < N_PB; i++) {
        Py_buffer *v = &self->bufs[i];
        const int ro = i == P_W || i == P_KER; /* taps and kernel: read, may be read-only */
        if (PyObject_GetBuffer(arr[i], v, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT
                                          | (ro ? 0 : PyBUF_WRITABLE)) < 0)
            return -1;
        self->held++;
        if (i == P_FOUT)
            fout = v;
    }
    self->n = fout->len / 8;
    const Py_ssize_t n = self->n, K = self->K, h = self->h;
    const Py_ssize_t W = 2 * h + 1;
    /* values each array holds (the vectors: n) */
    const Py_ssize_t size[N_PB] = {2 * (K + 1) * n, K, n, n, 2, n, 2 * W * n, (h + 1) * 2 * n, W,
                                   n, 6 * n, n, 1, 1, n, n, n, n};
    for (int i = 0; i < N_PB; i++) {
        const Py_buffer *v = &self->bufs[i];
        const int ints = i == P_FCTR || i == P_WCTR || i == P_BCTR;
        const char *want = i == P_USE ? "?" : ints ? "l" : "d";
        int ok = v->format != NULL && (strcmp(v->format, want) == 0
                                       || (ints && strcmp(v->format, "q") == 0));
        ok = ok && v->itemsize == (i == P_USE ? 1 : 8) && v->len == size[i] * v->itemsize;
        if (!ok) {
            PyErr_Format(PyExc_ValueError, "%s: a contiguous %s array of %zd values",
                         names[i], i == P_USE ? "bool" : ints ? "int64" : "float64", size[i]);
            return -1;
        }
    }
    return 0;
}

/* A call on a bound Practice with its two arguments; else the exception, and 0. */
static int callable(Practice *self, Py_ssize_t nargs, const char *usage) {
    return bound_call(self->held, N_PB, "Practice", nargs, 2, usage);
}

/* out[j] = sum_k w[k] rows[k][j] over the m rows (n wide), summed in k's order for every j
 * (the row loop outside: each row read once, in memory order) */
static void weighted_rows(const double *w, Py_ssize_t m, const double *rows, Py_ssize_t n,
                          double *out) {
    for (Py_ssize_t j = 0; j < n; j++)
        out[j] = w[0] * rows[j];
    for (Py_ssize_t k = 1; k < m; k++) {
        const double wk = w[k], *row = rows + k * n;
        for (Py_ssize_t j = 0; j < n; j++)
            out[j] = out[j] + wk * row[j];
    }
}

/* PracticeFIR._put: a row into the ring, twice (every window one slice) */
static void put(Practice *self, const double *row) {
    const Py_ssize_t n = self->n, w = self->K + 1;
    int64_t *c = CTR(P_FCTR);
    const Py_ssize_t j = (Py_ssize_t)(c[F_COUNT] % w);
    memcpy(BUF(P_RING) + j * n, row, (size_t)n * sizeof(double));
    memcpy(BUF(P_RING) + (j + w) * n, row, (size_t)n * sizeof(double));
    c[F_COUNT] += 1;
}

static PyObject *Practice_push(Practice *self, PyObject *const *args, Py_ssize_t nargs) {
    if (!callable(self, nargs, "push(t_ns, q)"))
        return NULL;
    const long long t_ns = PyLong_AsLongLong(args[0]);
    if (t_ns == -1 && PyErr_Occurred())
        return NULL;
    Py_buffer qb;
    if (get_vector(args[1], self->n, &qb, "q", 0) < 0)
        return NULL;
    const double *q = qb.buf;
    double *last = BUF(P_LAST);
    int64_t *c = CTR(P_FCTR);
    const Py_ssize_t n = self->n;
    if (c[F_COUNT]) {
        const double gap = (double)(t_ns - c[F_T_NS]) * 1e-9 / self->dt;
        long long missed = (long long)nearbyint(gap) - 1; /* Python's round: half to even */
        if (missed > self->K + 1)
            missed = self->K + 1;
        double row[n > 0 ? n : 1];
        for (long long i = 1; i <= missed; i++) {
            const double f = (double)i / (double)(missed + 1);
            for (Py_ssize_t j = 0; j < n; j++)
                row[j] = last[j] + (q[j] - last[j]) * f;
            put(self, row);
        }
    }
    put(self, q);
    memcpy(last, q, (size_t)n * sizeof(double));
    c[F_T_NS] = t_ns;
    PyBuffer_Release(&qb);
    Py_RETURN_NONE;
}

/* PracticeBlend.add's window and sums for the sample's positions q, the model's q̈ k and the
 * filter's f (PracticeWindow.push, then the evaluation it makes due) */
static void blend_add(Practice *self, const double *q, const double *k, const double *f) {
    const Py_ssize_t n = self->n, h = self->h, W = 2 * h + 1;
    double *dis = BUF(P_DIS);
    for (Py_ssize_t j = 0; j < n; j++) {
        double d = k[j] - f[j];
        d = d * d;
        d = d - dis[j];
        d = d * self->fast;
        dis[j] = dis[j] + d;
    }
    int64_t *wc = CTR(P_WCTR);
    long long c = wc[0];
    const Py_ssize_t jq = (Py_ssize_t)(c % W);
    double *wq = BUF(P_WQ), *wx = BUF(P_WX);
    memcpy(wq + jq * n, q, (size_t)n * sizeof(double));
    memcpy(wq + (jq + W) * n, q, (size_t)n * sizeof(double));
    double *xs = wx + (Py_ssize_t)(c % (h + 1)) * 2 * n;
    memcpy(xs, k, (size_t)n * sizeof(double));
    memcpy(xs + n, f, (size_t)n * sizeof(double));
    wc[0] = c = c + 1;
    if (c < W || c % self->every)
        return;
    /* the practice of the sample h back: the kernel over the window, in order */
    const double *win = wq + (Py_ssize_t)(c % W) * n, *ker = BUF(P_KER);
    double *y = BUF(P_REF);
    weighted_rows(ker, W, win, n, y);
    const double *kx = wx + (Py_ssize_t)(c % (h + 1)) * 2 * n, *fx = kx + n;
    int64_t *ev = CTR(P_BCTR);
    ev[0] += 1;
    const double inv = 1.0 / (double)ev[0];
    const double a = self->alpha > inv ? self->alpha : inv; /* Python's max(alpha, 1 / evals) */
    double *s = BUF(P_S);
    for (Py_ssize_t j = 0; j < n; j++) {
        const double t[6] = {kx[j] * kx[j], kx[j] * fx[j], fx[j] * fx[j], y[j] * kx[j],
                             y[j] * fx[j], y[j] * y[j]};
        for (int r = 0; r < 6; r++) {
            double v = t[r] - s[r * n + j];
            v = v * a;
            s[r * n + j] = s[r * n + j] + v;
        }
    }
}

static PyObject *Practice_output(Practice *self, PyObject *const *args, Py_ssize_t nargs) {
    if (!callable(self, nargs, "output(dt, q)"))
        return NULL;
    const double dt = PyFloat_AsDouble(args[0]);
    if (dt == -1.0 && PyErr_Occurred())
        return NULL;
    Py_buffer qb;
    if (get_vector(args[1], self->n, &qb, "q", 0) < 0)
        return NULL;
    const Py_ssize_t n = self->n, K = self->K;
    const int64_t count = CTR(P_FCTR)[F_COUNT];
    double *w = BUF(P_PFW), *qdd = BUF(P_QDD);
    if (!(count > K)) { /* restarted: the model's output is the one there is */
        memset(w, 0, (size_t)n * sizeof(double));
        PyBuffer_Release(&qb);
        Py_RETURN_NONE;
    }
    /* PracticeFIR.estimate: sum_k w_k x(t - k dt) - x(t) sum_k w_k, the window oldest first */
    const double *win = BUF(P_RING) + (Py_ssize_t)(count % (K + 1)) * n, *taps = BUF(P_W);
    double *f = BUF(P_FOUT);
    weighted_rows(taps, K, win, n, f);
    for (Py_ssize_t j = 0; j < n; j++)
        f[j] = f[j] - win[K * n + j] * self->sum;
    blend_add(self, qb.buf, qdd, f);
    PyBuffer_Release(&qb);
    const double *target = BUF(P_TARGET), *share = BUF(P_SHARE);
    int done = 1;
    for (Py_ssize_t j = 0; j < n && done; j++)
        done = w[j] == target[j];
    if (!done) { /* fading: at most a step towards the target, never past it */
        const double step = dt / self->fade_s;
        for (Py_ssize_t j = 0; j < n; j++) {
            double d = target[j] - w[j];
            const int arrive = fabs(d) <= step;
            d = d < -step ? -step : d;
            d = d > step ? step : d;
            w[j] = arrive ? target[j] : w[j] + d;
        }
    }
    int any = 0;
    for (Py_ssize_t j = 0; j < n && !any; j++)
        any = w[j] != 0.0;
    if (!any)
        Py_RETURN_NONE;
    const unsigned char *use = self->bufs[P_USE].buf;
    const int whole = done && self->share == 1.0; /* every weight 0 or 1 */
    for (Py_ssize_t j = 0; j < n; j++) {
        double v = f[j] - qdd[j];
        v = v * share[j];
        if (!whole)
            v = v * w[j];
        f[j] = v;
        if (!whole || use[j])
            qdd[j] = qdd[j] + v;
    }
    Py_RETURN_NONE;
}

static PyMethodDef Practice_methods[] = {
    {"push", (PyCFunction)(void (*)(void))Practice_push, METH_FASTCALL,
     "PracticeFIR.push: the sample's positions (and the dropped ones on the line) into the ring"},
    {"output", (PyCFunction)(void (*)(void))Practice_output, METH_FASTCALL,
     "_practice_filter_output: the filter's q̈, the blend's sums, the fade, the output's q̈"},
    {NULL, NULL, 0, NULL},
};

PyTypeObject PracticeType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "forearm_dynamics.estimation._kalman_step.Practice",
    .tp_doc = "The practice filter's per-sample step, bound to its arrays (practice_step.py).",
    .tp_basicsize = sizeof(Practice),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Practice_init,
    .tp_dealloc = (destructor)Practice_dealloc,
    .tp_methods = Practice_methods,
};
