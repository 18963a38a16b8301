/* What the package's compiled extensions (_kalman_step, _noise_step, _muscle_step) all need
 * for a call on an object bound to arrays: one definition, inlined into each (no symbol
 * shared between them). setup.py puts this directory on their include path. */
#ifndef FOREARM_BUFFERS_H
#define FOREARM_BUFFERS_H
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>

/* A call's (n,) float64 contiguous array (aligned or not) into view, with the buffer `flags`
 * asked on top (PyBUF_WRITABLE for an output, else 0); else a ValueError naming `what`,
 * and -1. */
static inline int get_vector(PyObject *obj, Py_ssize_t n, Py_buffer *view, const char *what,
                             int flags) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | flags) < 0)
        return -1;
    if (view->itemsize != 8 || view->format == NULL
        || (strcmp(view->format, "d") != 0 && strcmp(view->format, "=d") != 0)
        || view->len != n * 8) {
        PyErr_Format(PyExc_ValueError, "%s: a contiguous float64 array of %zd values", what, n);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* A call on an object of type `type` bound to its arrays (held of need buffers held) with its
 * number of arguments; else the exception, and 0. */
static inline int bound_call(int held, int need, const char *type, Py_ssize_t nargs,
                             Py_ssize_t expected, const char *usage) {
    if (held != need) {
        PyErr_Format(PyExc_RuntimeError, "%s is not bound to its arrays", type);
        return 0;
    }
    if (nargs != expected) {
        PyErr_SetString(PyExc_TypeError, usage);
        return 0;
    }
    return 1;
}

#endif
