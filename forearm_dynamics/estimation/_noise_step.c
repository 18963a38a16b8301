/* The noise estimator's per-sample store in one call (noise_step.py says why).
 *
 * Store(ctr, rate, raw, rawt, wring, wt, vring, vt, params) binds the estimator's own arrays
 * (noise_store.py: ctr int64 and rate float64, indexed as FIELDS lists them, raw (2 cap, n),
 * rawt (2 cap,), wring (4, n), wt (4,), vring (3, n), vt (3,), all C-contiguous and writable;
 * they must outlive the Store, which holds a buffer of each) and noise_store.py's constants,
 * params = (GAP_PERIODS, GAP_MIN_S, RATE_ALPHA, NOMINAL_TOL, NEW_RATE, DENSE_PERIOD_S,
 * DENSE_STRIDE, SAME_NS).
 *   store(t_ns, q, qd_or_None) -> the evaluations due (1 white, 2 position, 4 velocity), as
 *       SampleRings._store returns them, having done what it does: the rate, the
 *       counters, the rings. It returns -1 (NOT_STORED) with nothing written for what it
 *       leaves to _store: no stamp before this one (a first sample, a restart), no period
 *       yet, a new rate (the ring is reallocated), a ring bound for another stride.
 * Built with -ffp-contract=off: the rate's products and sums rounded as Python rounds them.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

/* noise_store.Ctr, then noise_store.Rate, in their order (noise_step.bind compares FIELDS) */
enum { STARTED, ORIGIN, HAS_LAST, LAST_NS, LAST_D, SAME, COUNT, WCOUNT, VCOUNT, CAP, STRIDE,
       EVERY, N_CTR };
enum { DT, DT_AVG, STRIDE_DT, N_RATE };
#define FIELDS \
    "STARTED ORIGIN HAS_LAST LAST_NS LAST_D SAME COUNT WCOUNT VCOUNT CAP STRIDE EVERY " \
    "DT DT_AVG STRIDE_DT"
#define NOT_STORED (-1)
#define N_BUFS 8

typedef struct {
    PyObject_HEAD
    Py_buffer bufs[N_BUFS]; /* ctr, rate, raw, rawt, wring, wt, vring, vt */
    int held; /* how many of bufs are held */
    Py_ssize_t n;
    double gap_periods, gap_min_s, rate_alpha, nominal_tol, new_rate, dense_period_s;
    long long dense_stride, same_ns;
} Store;

/* Python's a % b for b > 0 (never negative) */
static long long pymod(long long a, long long b) {
    const long long m = a % b;
    return m < 0 ? m + b : m;
}

static int get_vector(PyObject *obj, Py_ssize_t n, Py_buffer *view, const char *what) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return -1;
    if (view->format == NULL || strcmp(view->format, "d") != 0 || view->len != n * 8) {
        PyErr_Format(PyExc_ValueError, "%s: a contiguous float64 array of %zd values", what, n);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

static void release_all(Store *self) {
    for (int i = 0; i < self->held; i++)
        PyBuffer_Release(&self->bufs[i]);
    self->held = 0;
}

static void Store_dealloc(Store *self) {
    release_all(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int Store_init(Store *self, PyObject *args, PyObject *kwds) {
    PyObject *arr[N_BUFS];
    static char *names[] = {"ctr", "rate", "raw", "rawt", "wring", "wt", "vring", "vt",
                            "params", NULL};
    /* rows of a 2-d array (-1: twice the ring, 2 CAP), 0: a vector; lengths of vectors */
    static const int rows[] = {0, 0, -1, 0, 4, 0, 3, 0};
    PyObject *params;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOOOOOOOO", names, &arr[0], &arr[1], &arr[2],
                                     &arr[3], &arr[4], &arr[5], &arr[6], &arr[7], &params))
        return -1;
    release_all(self);
    if (!PyArg_ParseTuple(params, "ddddddLL", &self->gap_periods, &self->gap_min_s,
                          &self->rate_alpha, &self->nominal_tol, &self->new_rate,
                          &self->dense_period_s, &self->dense_stride, &self->same_ns))
        return -1;
    if (self->dense_stride < 1) {
        PyErr_SetString(PyExc_ValueError, "params: DENSE_STRIDE must be at least 1");
        return -1;
    }
    self->n = -1;
    for (int i = 0; i < N_BUFS; i++) {
        Py_buffer *v = &self->bufs[i];
        if (PyObject_GetBuffer(arr[i], v, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_WRITABLE) < 0)
            return -1;
        self->held++;
        const char *fmt = i == 0 ? "l" : "d";
        int ok = v->format != NULL && (strcmp(v->format, fmt) == 0
                                       || (i == 0 && strcmp(v->format, "q") == 0))
                 && v->itemsize == 8;
        if (ok && i == 0)
            ok = v->ndim == 1 && v->shape[0] == N_CTR;
        else if (ok && i == 1)
            ok = v->ndim == 1 && v->shape[0] == N_RATE;
        else if (ok && rows[i]) {
            if (self->n < 0 && v->ndim == 2)
                self->n = v->shape[1];
            ok = v->ndim == 2 && v->shape[1] == self->n
                 && (rows[i] > 0 ? v->shape[0] == rows[i] : v->shape[0] % 2 == 0);
        } else if (ok) { /* the times of the ring before it */
            ok = v->ndim == 1 && v->shape[0] == self->bufs[i - 1].shape[0];
        }
        if (!ok) {
            PyErr_Format(PyExc_ValueError,
                         "%s: a writable contiguous %s array of noise_store.py's shape",
                         names[i], i == 0 ? "int64" : "float64");
            return -1;
        }
    }
    return 0;
}

static PyObject *Store_store(Store *self, PyObject *const *args, Py_ssize_t nargs) {
    if (self->held != N_BUFS) {
        PyErr_SetString(PyExc_RuntimeError, "Store is not bound to its arrays");
        return NULL;
    }
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "store(t_ns, q, qd_or_None)");
        return NULL;
    }
    const long long t_ns = PyLong_AsLongLong(args[0]);
    if (t_ns == -1 && PyErr_Occurred())
        return NULL;
    const Py_ssize_t n = self->n;
    int64_t *c = self->bufs[0].buf;
    double *r = self->bufs[1].buf;
    const Py_ssize_t ring = self->bufs[2].shape[0] / 2;
    if (!c[STARTED] || !c[HAS_LAST] || r[DT] == 0.0 || c[CAP] != ring || ring == 0)
        return PyLong_FromLong(NOT_STORED);
    Py_buffer qb, qdb;
    if (get_vector(args[1], n, &qb, "q") < 0)
        return NULL;
    const int vel = args[2] != Py_None;
    if (vel && get_vector(args[2], n, &qdb, "qd") < 0) {
        PyBuffer_Release(&qb);
        return NULL;
    }
    /* the rate first: a new one is _store's, and nothing is written */
    const long long d = t_ns - c[LAST_NS];
    const double step = (double)d * 1e-9, nominal = r[DT];
    const int gap = step > fmax(self->gap_periods * nominal, self->gap_min_s);
    double avg = r[DT_AVG];
    if (!gap) {
        avg += self->rate_alpha * (step - avg);
        if (fabs(avg - r[STRIDE_DT]) > self->new_rate * r[STRIDE_DT]) {
            PyBuffer_Release(&qb);
            if (vel)
                PyBuffer_Release(&qdb);
            return PyLong_FromLong(NOT_STORED);
        }
    }
    const double t_s = (double)(t_ns - c[ORIGIN]) * 1e-9;
    c[LAST_NS] = t_ns;
    if (gap) {
        c[COUNT] = c[VCOUNT] = c[WCOUNT] = 0;
    } else {
        r[DT_AVG] = avg;
        if (fabs(avg - nominal) > self->nominal_tol * nominal)
            r[DT] = avg;
    }
    c[SAME] = llabs(d - c[LAST_D]) <= self->same_ns ? c[SAME] + 1 : 0;
    c[LAST_D] = d;
    const double dt = r[DT];
    const long long dense = dt < self->dense_period_s ? self->dense_stride : 1;
    const size_t row = (size_t)n * sizeof(double);
    long due = 0;
    /* white: every dense-th window of four consecutive samples */
    long long k = c[WCOUNT];
    Py_ssize_t h = (Py_ssize_t)(k % 4);
    c[WCOUNT] = ++k;
    if (pymod(-k, dense) < 4) {
        memcpy((double *)self->bufs[4].buf + h * n, qb.buf, row);
        ((double *)self->bufs[5].buf)[h] = t_s;
        if (k % dense == 0 && k >= 4)
            due |= 1;
    }
    /* position: the ring, each sample twice */
    const long long cap = c[CAP];
    k = c[COUNT];
    h = (Py_ssize_t)(k % cap);
    double *raw = self->bufs[2].buf, *rawt = self->bufs[3].buf;
    memcpy(raw + h * n, qb.buf, row);
    memcpy(raw + (h + cap) * n, qb.buf, row);
    rawt[h] = rawt[h + cap] = t_s;
    c[COUNT] = ++k;
    if (k >= cap && k % c[EVERY] == 0)
        due |= 2;
    PyBuffer_Release(&qb);
    /* velocity: the three samples of the next evaluation */
    if (vel) {
        k = ++c[VCOUNT];
        if (pymod(-k, dense) < 3) {
            h = (Py_ssize_t)(k % 3);
            memcpy((double *)self->bufs[6].buf + h * n, qdb.buf, row);
            ((double *)self->bufs[7].buf)[h] = t_s;
            if (k >= 3 && k % dense == 0)
                due |= 4;
        }
        PyBuffer_Release(&qdb);
    }
    return PyLong_FromLong(due);
}

static PyMethodDef Store_methods[] = {
    {"store", (PyCFunction)(void (*)(void))Store_store, METH_FASTCALL,
     "the sample into the rings; returns the evaluations due, or -1 (left to _store)"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject StoreType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "forearm_dynamics.estimation._noise_step.Store",
    .tp_doc = "The noise estimator's per-sample store, bound to its arrays.",
    .tp_basicsize = sizeof(Store),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Store_init,
    .tp_dealloc = (destructor)Store_dealloc,
    .tp_methods = Store_methods,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_noise_step", "See noise_step.py.", -1, NULL, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__noise_step(void) {
    if (PyType_Ready(&StoreType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    if (PyModule_AddStringConstant(m, "FIELDS", FIELDS) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    Py_INCREF(&StoreType);
    if (PyModule_AddObject(m, "Store", (PyObject *)&StoreType) < 0) {
        Py_DECREF(&StoreType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
