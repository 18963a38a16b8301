/* The Kalman filter's per-sample arithmetic in one call each (kalman_step.py says why).
 *
 * Step(x, t3, e, kp, kv, out, keep_q, keep_qd) binds the filter's own arrays (float64,
 * C-contiguous: x, t3, kp, kv, out (3, n), e (2, n), keep_q, keep_qd (n,)); they are written
 * in place and must outlive the Step (it holds a buffer of each).
 *   predict_innovate(q, qd_or_None, dt) -> max |e[0]|: t3 = F(dt) x (white-jerk transition),
 *       e[0] = q - t3[0], e[1] = qd - t3[1] when qd is given.
 *   correct(vel, q_or_None, qd_or_None, copy_out) -> None: x = (kp * e[0] + kv * e[1]) + t3
 *       (without the kv term when vel is false): the order of the numpy path's operations;
 *       then keep_q = q and keep_qd = qd where given, and out = x if copy_out.
 * Gains(state, gidx, r_gate, kp, kv, sig) binds the noise groups' state (float64 (G, 24), the
 * columns of noise_groups.Col, exported here and checked at bind time), the joints' group
 * indices (intp (n,)), the gate's noise (n,) and the per-joint gains and innovation stds it
 * writes (kp, kv (3, n), sig (n,)).
 *   step(dt, period, psd, vel, jitter) -> 1 (gains written), 0 (all kept) or -1 (a group is
 *       not seated at the steady state of this period: nothing written, Python's loop runs):
 *       noise_groups.NoiseGroups._python_covariance_step for seated groups, the same
 *       operations in the same order (ca_model.prior, ca_model.measurement_update).
 * Built with -ffp-contract=off: no fused multiply-add, each product and sum rounded as the
 * numpy path rounds it (test_kalman_step.py compares the two; test_group_step.py the gains).
 */
#include "_kalman_step.h" /* get_vector, bound_call; Practice, registered below */

#include <math.h>
#include <string.h>

typedef struct {
    PyObject_HEAD
    Py_buffer bufs[8]; /* x, t3, e, kp, kv, out, keep_q, keep_qd */
    int held; /* how many of bufs are held */
    Py_ssize_t n;
} Step;

/* A call on a bound Step with its number of arguments; else the exception, and 0. */
static int callable(Step *self, Py_ssize_t nargs, Py_ssize_t expected, const char *usage) {
    return bound_call(self->held, 8, "Step", nargs, expected, usage);
}

static void Step_dealloc(Step *self) {
    for (int i = 0; i < self->held; i++)
        PyBuffer_Release(&self->bufs[i]);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int Step_init(Step *self, PyObject *args, PyObject *kwds) {
    PyObject *arr[8];
    static char *names[] = {"x", "t3", "e", "kp", "kv", "out", "keep_q", "keep_qd", NULL};
    static const int rows[] = {3, 3, 2, 3, 3, 3, 0, 0}; /* 0: a vector (n,) */
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOOOOOOO", names, &arr[0], &arr[1], &arr[2],
                                     &arr[3], &arr[4], &arr[5], &arr[6], &arr[7]))
        return -1;
    for (int i = 0; i < self->held; i++)
        PyBuffer_Release(&self->bufs[i]);
    self->held = 0;
    for (int i = 0; i < 8; i++) {
        Py_buffer *v = &self->bufs[i];
        if (PyObject_GetBuffer(arr[i], v, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_WRITABLE) < 0)
            return -1;
        self->held++;
        if (i == 0)
            self->n = v->ndim == 2 ? v->shape[1] : -1;
        const int ok = rows[i] ? v->ndim == 2 && v->shape[0] == rows[i] && v->shape[1] == self->n
                               : v->ndim == 1 && v->shape[0] == self->n;
        if (v->format == NULL || strcmp(v->format, "d") != 0 || !ok) {
            if (rows[i])
                PyErr_Format(PyExc_ValueError, "%s: a writable contiguous float64 array (%d, n)",
                             names[i], rows[i]);
            else
                PyErr_Format(PyExc_ValueError, "%s: a writable contiguous float64 array (n,)",
                             names[i]);
            return -1;
        }
    }
    return 0;
}

static PyObject *Step_predict_innovate(Step *self, PyObject *const *args, Py_ssize_t nargs) {
    if (!callable(self, nargs, 3, "predict_innovate(q, qd_or_None, dt)"))
        return NULL;
    double dt = PyFloat_AsDouble(args[2]);
    if (dt == -1.0 && PyErr_Occurred())
        return NULL;
    const Py_ssize_t n = self->n;
    Py_buffer qb, qdb;
    if (get_vector(args[0], n, &qb, "q", 0) < 0)
        return NULL;
    const int vel = args[1] != Py_None;
    if (vel && get_vector(args[1], n, &qdb, "qd", 0) < 0) {
        PyBuffer_Release(&qb);
        return NULL;
    }
    const double *x = self->bufs[0].buf, *q = qb.buf, *qd = vel ? qdb.buf : NULL;
    double *t3 = self->bufs[1].buf, *e = self->bufs[2].buf;
    const double h = 0.5 * dt * dt;
    double m = 0.0;
    for (Py_ssize_t j = 0; j < n; j++) {
        const double x0 = x[j], x1 = x[n + j], x2 = x[2 * n + j];
        const double p0 = x0 + dt * x1 + h * x2, p1 = x1 + dt * x2;
        t3[j] = p0;
        t3[n + j] = p1;
        t3[2 * n + j] = x2;
        const double e0 = q[j] - p0;
        e[j] = e0;
        if (vel)
            e[n + j] = qd[j] - p1;
        if (fabs(e0) > m)
            m = fabs(e0);
    }
    PyBuffer_Release(&qb);
    if (vel)
        PyBuffer_Release(&qdb);
    return PyFloat_FromDouble(m);
}

static PyObject *Step_correct(Step *self, PyObject *const *args, Py_ssize_t nargs) {
    if (!callable(self, nargs, 4, "correct(vel, q_or_None, qd_or_None, copy_out)"))
        return NULL;
    const int vel = PyObject_IsTrue(args[0]), copy_out = PyObject_IsTrue(args[3]);
    if (vel < 0 || copy_out < 0)
        return NULL;
    const Py_ssize_t n = self->n;
    /* the vectors to keep first: a refused one leaves every array as it was */
    Py_buffer keep[2];
    int kept = 0;
    for (int k = 0; k < 2; k++) {
        if (args[1 + k] == Py_None)
            continue;
        if (get_vector(args[1 + k], n, &keep[k], k ? "qd" : "q", 0) < 0) {
            if (kept)
                PyBuffer_Release(&keep[0]);
            return NULL;
        }
        kept |= 1 << k;
    }
    double *x = self->bufs[0].buf;
    const double *t3 = self->bufs[1].buf, *e = self->bufs[2].buf;
    const double *kp = self->bufs[3].buf, *kv = self->bufs[4].buf;
    for (Py_ssize_t r = 0; r < 3; r++) {
        for (Py_ssize_t j = 0; j < n; j++) {
            const Py_ssize_t i = r * n + j;
            double v = kp[i] * e[j];
            if (vel)
                v += kv[i] * e[n + j];
            x[i] = v + t3[i];
        }
    }
    if (copy_out)
        memcpy(self->bufs[5].buf, x, 3 * n * sizeof(double));
    for (int k = 0; k < 2; k++) {
        if (kept & (1 << k)) {
            memcpy(self->bufs[6 + k].buf, keep[k].buf, n * sizeof(double));
            PyBuffer_Release(&keep[k]);
        }
    }
    Py_RETURN_NONE;
}

static PyMethodDef Step_methods[] = {
    {"predict_innovate", (PyCFunction)(void (*)(void))Step_predict_innovate, METH_FASTCALL,
     "t3 = F(dt) x; e = (q, qd) - t3[:2]; returns max |e[0]|"},
    {"correct", (PyCFunction)(void (*)(void))Step_correct, METH_FASTCALL,
     "x = kp * e[0] (+ kv * e[1]) + t3; keep_q = q, keep_qd = qd where given; out = x"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject StepType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "forearm_dynamics.estimation._kalman_step.Step",
    .tp_doc = "The Kalman filter's per-sample arithmetic, bound to its arrays.",
    .tp_basicsize = sizeof(Step),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Step_init,
    .tp_dealloc = (destructor)Step_dealloc,
    .tp_methods = Step_methods,
};

/* -- Gains: the noise groups' covariance step for groups seated at their steady state ------- */

/* The columns of a group's row: noise_groups.Col (kalman_step.bind_gains checks them). */
enum { C_P = 0, C_M = 6, C_K = 12, C_DT = 18, C_STILL = 19, C_SEATED = 20, C_R = 21, C_RV = 22,
       C_SETTLING = 23, C_WIDTH = 24 };

typedef struct {
    PyObject_HEAD
    Py_buffer bufs[6]; /* state, gidx, r_gate, kp, kv, sig */
    int held;
    Py_ssize_t n, groups;
} Gains;

static void Gains_dealloc(Gains *self) {
    for (int i = 0; i < self->held; i++)
        PyBuffer_Release(&self->bufs[i]);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int Gains_init(Gains *self, PyObject *args, PyObject *kwds) {
    PyObject *arr[6];
    static char *names[] = {"state", "gidx", "r_gate", "kp", "kv", "sig", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOOOOO", names, &arr[0], &arr[1], &arr[2],
                                     &arr[3], &arr[4], &arr[5]))
        return -1;
    for (int i = 0; i < self->held; i++)
        PyBuffer_Release(&self->bufs[i]);
    self->held = 0;
    for (int i = 0; i < 6; i++) {
        Py_buffer *v = &self->bufs[i];
        static const char *want[] = {
            "a writable contiguous float64 array (groups, 24)", "a contiguous intp array (n,)",
            "a contiguous float64 array (n,)", "a writable contiguous float64 array (3, n)",
            "a writable contiguous float64 array (3, n)", "a writable contiguous float64 array (n,)"};
        const int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT
                          | (i == 0 || i >= 3 ? PyBUF_WRITABLE : 0);
        if (PyObject_GetBuffer(arr[i], v, flags) < 0) { /* read-only, strided: name it */
            PyErr_Clear();
            PyErr_Format(PyExc_ValueError, "%s: %s", names[i], want[i]);
            return -1;
        }
        self->held++;
        int ok;
        if (i == 0) {
            ok = v->ndim == 2 && v->shape[1] == C_WIDTH && v->shape[0] > 0;
            self->groups = ok ? v->shape[0] : 0;
        } else if (i == 1) {
            self->n = v->ndim == 1 ? v->shape[0] : -1;
            ok = v->ndim == 1 && v->itemsize == sizeof(Py_ssize_t) && v->format != NULL
                 && v->format[0] != '\0' && strchr("lqn", v->format[0]) != NULL
                 && v->format[1] == '\0';
        } else if (i == 3 || i == 4) {
            ok = v->ndim == 2 && v->shape[0] == 3 && v->shape[1] == self->n;
        } else {
            ok = v->ndim == 1 && v->shape[0] == self->n;
        }
        if (i != 1)
            ok = ok && v->format != NULL && strcmp(v->format, "d") == 0;
        if (!ok) {
            PyErr_Format(PyExc_ValueError, "%s: %s", names[i], want[i]);
            return -1;
        }
    }
    return 0;
}

/* Does group row g need this step, and is it seated (Python's loop, the same tests)? */
static int needs_step(const double *g, double dt, double period, double jitter, int near,
                      int *seated) {
    const int still = g[C_STILL] != 0.0;
    if (still && dt == g[C_DT])
        return 0;
    *seated = g[C_SEATED] != 0.0 && fabs(g[C_SEATED] - period) <= jitter * period;
    return !(*seated && still && near);
}

static PyObject *Gains_step(Gains *self, PyObject *const *args, Py_ssize_t nargs) {
    if (!bound_call(self->held, 6, "Gains", nargs, 5, "step(dt, period, psd, vel, jitter)"))
        return NULL;
    double v[4];
    for (int i = 0; i < 4; i++) {
        const int a = i < 3 ? i : 4;
        v[i] = PyFloat_AsDouble(args[a]);
        if (v[i] == -1.0 && PyErr_Occurred())
            return NULL;
    }
    const double dt = v[0], period = v[1], psd = v[2], jitter = v[3];
    const int vel = PyObject_IsTrue(args[3]);
    if (vel < 0)
        return NULL;
    const Py_ssize_t n = self->n, groups = self->groups;
    double *state = self->bufs[0].buf;
    const Py_ssize_t *gidx = self->bufs[1].buf;
    const int near = fabs(dt - period) <= jitter * period;
    int seated;
    for (Py_ssize_t i = 0; i < groups; i++) /* any group off its steady state: Python's loop */
        if (needs_step(state + i * C_WIDTH, dt, period, jitter, near, &seated) && !seated)
            return PyLong_FromLong(-1);
    for (Py_ssize_t j = 0; j < n; j++) {
        if (gidx[j] < 0 || gidx[j] >= groups) {
            PyErr_Format(PyExc_ValueError, "gidx[%zd] = %zd: not a group of %zd", j, gidx[j], groups);
            return NULL;
        }
    }
    int changed = 0;
    for (Py_ssize_t i = 0; i < groups; i++) {
        double *g = state + i * C_WIDTH;
        if (!needs_step(g, dt, period, jitter, near, &seated))
            continue;
        /* ca_model.prior: M = F P F^T + Q at dt */
        const double *p = g + C_P;
        const double p00 = p[0], p01 = p[1], p02 = p[2], p11 = p[3], p12 = p[4], p22 = p[5];
        const double h = 0.5 * dt * dt;
        const double a0 = p00 + dt * p01 + h * p02, a1 = p01 + dt * p11 + h * p12,
                     a2 = p02 + dt * p12 + h * p22;
        const double b1 = p11 + dt * p12, b2 = p12 + dt * p22;
        const double s = psd * dt;
        const double m00 = a0 + dt * a1 + h * a2 + s * h * h / 5, m01 = a1 + dt * a2 + s * h * dt / 4,
                     m02 = a2 + s * h / 3, m11 = b1 + dt * b2 + s * h * 2 / 3, m12 = b2 + s * dt / 2,
                     m22 = p22 + s;
        double *m = g + C_M, *k = g + C_K;
        m[0] = m00, m[1] = m01, m[2] = m02, m[3] = m11, m[4] = m12, m[5] = m22;
        /* ca_model.measurement_update's gain (the posterior stays: the group is seated) */
        const double r2 = g[C_R] * g[C_R], s00 = m00 + r2;
        if (!vel) {
            k[0] = m00 / s00, k[1] = m01 / s00, k[2] = m02 / s00;
        } else {
            const double s11 = m11 + g[C_RV] * g[C_RV];
            const double det = s00 * s11 - m01 * m01;
            const double i00 = s11 / det, i01 = -m01 / det, i11 = s00 / det;
            k[0] = m00 * i00 + m01 * i01, k[3] = m00 * i01 + m01 * i11; /* q row */
            k[1] = m01 * i00 + m11 * i01, k[4] = m01 * i01 + m11 * i11; /* q̇ row */
            k[2] = m02 * i00 + m12 * i01, k[5] = m02 * i01 + m12 * i11; /* q̈ row */
        }
        g[C_DT] = dt;
        g[C_STILL] = near ? 1.0 : 0.0;
        changed = 1;
    }
    if (changed) { /* the per-joint gains and innovation stds (NoiseGroups._joint_gains) */
        double *kp = self->bufs[3].buf, *kv = self->bufs[4].buf, *sig = self->bufs[5].buf;
        const double *rg = self->bufs[2].buf;
        for (Py_ssize_t j = 0; j < n; j++) {
            const double *g = state + gidx[j] * C_WIDTH;
            for (int r = 0; r < 3; r++) {
                kp[r * n + j] = g[C_K + r];
                if (vel)
                    kv[r * n + j] = g[C_K + 3 + r];
            }
            sig[j] = sqrt(g[C_M] + rg[j] * rg[j]);
        }
    }
    return PyLong_FromLong(changed);
}

static PyMethodDef Gains_methods[] = {
    {"step", (PyCFunction)(void (*)(void))Gains_step, METH_FASTCALL,
     "the seated groups' gains at dt; 1 written, 0 kept, -1 Python's loop must run"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject GainsType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "forearm_dynamics.estimation._kalman_step.Gains",
    .tp_doc = "The noise groups' covariance step, bound to their state and the joints' gains.",
    .tp_basicsize = sizeof(Gains),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Gains_init,
    .tp_dealloc = (destructor)Gains_dealloc,
    .tp_methods = Gains_methods,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_kalman_step", "See kalman_step.py.", -1, NULL, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__kalman_step(void) {
    if (PyType_Ready(&StepType) < 0 || PyType_Ready(&GainsType) < 0
        || PyType_Ready(&PracticeType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    Py_INCREF(&StepType);
    if (PyModule_AddObject(m, "Step", (PyObject *)&StepType) < 0) {
        Py_DECREF(&StepType);
        Py_DECREF(m);
        return NULL;
    }
    Py_INCREF(&GainsType);
    if (PyModule_AddObject(m, "Gains", (PyObject *)&GainsType) < 0) {
        Py_DECREF(&GainsType);
        Py_DECREF(m);
        return NULL;
    }
    Py_INCREF(&PracticeType);
    if (PyModule_AddObject(m, "Practice", (PyObject *)&PracticeType) < 0) {
        Py_DECREF(&PracticeType);
        Py_DECREF(m);
        return NULL;
    }
    static const char *cols[] = {"P", "M", "K", "DT", "STILL", "SEATED", "R", "RV", "SETTLING",
                                 "WIDTH"};
    static const int at[] = {C_P, C_M, C_K, C_DT, C_STILL, C_SEATED, C_R, C_RV, C_SETTLING,
                             C_WIDTH};
    for (int i = 0; i < 10; i++) { /* the layout, for noise_groups.Col to be checked against */
        if (PyModule_AddIntConstant(m, cols[i], at[i]) < 0) {
            Py_DECREF(m);
            return NULL;
        }
    }
    return m;
}
