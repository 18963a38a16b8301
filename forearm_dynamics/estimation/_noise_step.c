/* The noise estimator's per-sample store, and the evaluations it makes due, in one call
 * (noise_step.py says why).
 *
 * Store(ctr, rate, raw, rawt, wring, wt, vring, vt, ms_w, ms_v, nclip_v, ms, nclip, params)
 * binds the estimator's own arrays (noise_store.py: ctr int64 and rate float64, indexed as
 * FIELDS lists them, raw (2 cap, n), rawt (2 cap,), wring (4, n), wt (4,), vring (3, n),
 * vt (3,); noise.py: ms_w, ms_v, ms (n,) float64, nclip_v, nclip (n,) int64; all
 * C-contiguous and writable; they must outlive the Store, which holds a buffer of each) and
 * the constants, params = (GAP_PERIODS, GAP_MIN_S, RATE_ALPHA, NOMINAL_TOL, NEW_RATE,
 * DENSE_PERIOD_S, DENSE_STRIDE, SAME_NS, TAU_S, CLIP_SIGMAS, CLIP_RUN, MIN_EVALUATIONS,
 * WINDOW_STRETCH, BLOCK_SPREAD_RATIO, MIN_BLOCK).
 *   store(t_ns, q, qd_or_None) -> the evaluations left due (2: a position evaluation it
 *       leaves to noise.py; else 0), having done what SampleRings._store does (the rate,
 *       the counters, the rings) and the evaluations it made due (_noise_evaluations.c).
 *       It returns -1 (NOT_STORED) with nothing written for what it leaves to _store: no
 *       stamp before this one (a first sample, a restart), no period yet, a new rate (the
 *       ring is reallocated), a ring bound for another stride.
 * Built with -ffp-contract=off: every product and sum rounded as Python and numpy round them.
 */
#include "_noise_step.h"

static void release_all(Store *self) {
    for (int i = 0; i < self->held; i++)
        PyBuffer_Release(&self->bufs[i]);
    self->held = 0;
}

static void Store_dealloc(Store *self) {
    release_all(self);
    PyMem_Free(self->z);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int Store_init(Store *self, PyObject *args, PyObject *kwds) {
    PyObject *arr[N_BUFS];
    static char *names[] = {"ctr", "rate", "raw", "rawt", "wring", "wt", "vring", "vt",
                            "ms_w", "ms_v", "nclip_v", "ms", "nclip", "params", NULL};
    /* rows of a 2-d array (-1: twice the ring, 2 CAP), 0: the times of the ring before it,
       -2: a joint vector (n,) */
    static const int rows[] = {0, 0, -1, 0, 4, 0, 3, 0, -2, -2, -2, -2, -2};
    PyObject *params;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOOOOOOOOOOOOO", names, &arr[0], &arr[1],
                                     &arr[2], &arr[3], &arr[4], &arr[5], &arr[6], &arr[7],
                                     &arr[8], &arr[9], &arr[10], &arr[11], &arr[12], &params))
        return -1;
    release_all(self);
    if (!PyArg_ParseTuple(params, "ddddddLLddLLddL", &self->gap_periods, &self->gap_min_s,
                          &self->rate_alpha, &self->nominal_tol, &self->new_rate,
                          &self->dense_period_s, &self->dense_stride, &self->same_ns,
                          &self->tau_s, &self->clip_sigmas, &self->clip_run,
                          &self->min_evaluations, &self->window_stretch,
                          &self->block_spread_ratio, &self->min_block))
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
        const int ints = i == B_CTR || i == B_NCLIPV || i == B_NCLIP;
        int ok = v->format != NULL && (strcmp(v->format, ints ? "l" : "d") == 0
                                       || (ints && strcmp(v->format, "q") == 0))
                 && v->itemsize == 8;
        if (ok && i == B_CTR)
            ok = v->ndim == 1 && v->shape[0] == N_CTR;
        else if (ok && i == B_RATE)
            ok = v->ndim == 1 && v->shape[0] == N_RATE;
        else if (ok && rows[i] == -2)
            ok = v->ndim == 1 && v->shape[0] == self->n;
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
                         names[i], ints ? "int64" : "float64");
            return -1;
        }
    }
    PyMem_Free(self->z);
    const size_t cap = (size_t)self->bufs[B_RAW].shape[0] / 2;
    self->z = PyMem_Malloc(((size_t)(BLOCKS + 1) * (size_t)self->n + cap + 1) * sizeof(double));
    if (self->z == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    return 0;
}


static PyObject *Store_store(Store *self, PyObject *const *args, Py_ssize_t nargs) {
    if (!bound_call(self->held, N_BUFS, "Store", nargs, 3, "store(t_ns, q, qd_or_None)"))
        return NULL;
    const long long t_ns = PyLong_AsLongLong(args[0]);
    if (t_ns == -1 && PyErr_Occurred())
        return NULL;
    const Py_ssize_t n = self->n;
    int64_t *c = self->bufs[B_CTR].buf;
    double *r = self->bufs[B_RATE].buf;
    const Py_ssize_t ring = self->bufs[B_RAW].shape[0] / 2;
    if (!c[STARTED] || !c[HAS_LAST] || r[DT] == 0.0 || c[CAP] != ring || ring == 0)
        return PyLong_FromLong(NOT_STORED);
    Py_buffer qb, qdb;
    if (get_vector(args[1], n, &qb, "q", 0) < 0)
        return NULL;
    const int vel = args[2] != Py_None;
    if (vel && get_vector(args[2], n, &qdb, "qd", 0) < 0) {
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
        memcpy((double *)self->bufs[B_WRING].buf + h * n, qb.buf, row);
        ((double *)self->bufs[B_WT].buf)[h] = t_s;
        if (k % dense == 0 && k >= 4)
            due |= 1;
    }
    /* position: the ring, each sample twice */
    const long long cap = c[CAP];
    k = c[COUNT];
    h = (Py_ssize_t)(k % cap);
    double *raw = self->bufs[B_RAW].buf, *rawt = self->bufs[B_RAWT].buf;
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
            memcpy((double *)self->bufs[B_VRING].buf + h * n, qdb.buf, row);
            ((double *)self->bufs[B_VT].buf)[h] = t_s;
            if (k >= 3 && k % dense == 0)
                due |= 4;
        }
        PyBuffer_Release(&qdb);
    }
    /* the evaluations, in noise.py's order (they read and write apart); a position one this
       cannot do is left due, to noise.py */
    if (due & 1)
        white_evaluation(self, c, r, dense);
    if ((due & 2) && position_evaluation(self, c, r) == 0)
        due &= ~2L;
    if (due & 4)
        velocity_evaluation(self, c, dense);
    return PyLong_FromLong(due & 2);
}

static PyMethodDef Store_methods[] = {
    {"store", (PyCFunction)(void (*)(void))Store_store, METH_FASTCALL,
     "the sample into the rings, and its white and velocity evaluations; returns the position "
     "evaluation due (2) or 0, or -1 (left to _store)"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject StoreType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "forearm_dynamics.estimation._noise_step.Store",
    .tp_doc = "The noise estimator's per-sample store and evaluations, bound to its arrays.",
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
