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
 * Built with -ffp-contract=off: no fused multiply-add, each product and sum rounded as the
 * numpy path rounds it (test_kalman_step.py compares the two).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

typedef struct {
    PyObject_HEAD
    Py_buffer bufs[8]; /* x, t3, e, kp, kv, out, keep_q, keep_qd */
    int held; /* how many of bufs are held */
    Py_ssize_t n;
} Step;

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

/* A call on a bound Step with its number of arguments; else the exception, and 0. */
static int callable(Step *self, Py_ssize_t nargs, Py_ssize_t expected, const char *usage) {
    if (self->held != 8) {
        PyErr_SetString(PyExc_RuntimeError, "Step is not bound to its arrays");
        return 0;
    }
    if (nargs != expected) {
        PyErr_SetString(PyExc_TypeError, usage);
        return 0;
    }
    return 1;
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
    if (get_vector(args[0], n, &qb, "q") < 0)
        return NULL;
    const int vel = args[1] != Py_None;
    if (vel && get_vector(args[1], n, &qdb, "qd") < 0) {
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
        if (get_vector(args[1 + k], n, &keep[k], k ? "qd" : "q") < 0) {
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

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_kalman_step", "See kalman_step.py.", -1, NULL, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__kalman_step(void) {
    if (PyType_Ready(&StepType) < 0)
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
    return m;
}
