/* The muscle node's per-sample arithmetic around the QP in two calls (muscle_step.py says why).
 *
 * Step(...) binds the surrogate's tables, the curves' constants and the arrays it writes (see
 * Step_init's names; float64 and int64, C-contiguous; written in place, held until the Step
 * goes):
 *   problem(q, qd, tau) -> None: the posture's moment arms R (n, 20) and lengths L (n,) (the
 *       polynomials: x = clip((q - centre) / half, -1, 1), the monomials, the sparse product),
 *       the path velocities V = -R qd, the unit forces (DeGroote-Fregly 2016, rigid tendon,
 *       not pennate), the QP's matrix A[j, i] = R[i, j] unit[i] and its right-hand sides = tau.
 *   finish(x, activations, forces, reserves) -> max(x): x clipped to [0, 1] in place,
 *       reserves = rhs - A x, forces = x unit, activations = x (the outputs may be unaligned
 *       views of a message's bytes: written by memcpy).
 * The same operations in numpy's order, built with -ffp-contract=off (no fused multiply-add);
 * what may round differently from numpy: exp and asinh (libm against numpy's own) and the sums
 * numpy hands to BLAS (V, the three-term force-length sum, A x). test_muscle_step.py bounds it.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "_buffers.h" /* get_vector, bound_call */

#define NJ 20
enum {
    CENTER, INV_HALF, VARIABLES, OUT, PA, PB, INDPTR, INDICES, DATA, ROWS, /* the surrogate */
    LTS, INV_L0, V_SCALE, F0_D1, F0_D4, F0, /* the curves */
    XE, MONO, BUF, I_V, UNIT, I_A, RHS_U, RHS_L, /* written */
    N_BUFS
};
static char *names[] = {"center", "inv_half", "variables", "out", "pa", "pb", "indptr",
                        "indices", "data", "rows", "lts", "inv_l0", "v_scale", "f0_d1", "f0_d4", "f0",
                        "xe", "mono", "buf", "v", "unit", "a", "rhs_u", "rhs_l", NULL};

/* The force-length's three curves and the force-velocity's constants (curves.py). */
static const double B1[3] = {0.8150671134243542, 0.433004984392647, 0.1};
static const double B2[3] = {1.055033428970575, 0.716775413397760, 1.0};
static const double B3[3] = {0.162384573599574, -0.029947116970696, 0.353553390593274};
static const double B4[3] = {0.063303448465465, 0.200356847296188, 0.0};
static const double D3 = -0.374;

typedef struct {
    PyObject_HEAD
    Py_buffer bufs[N_BUFS];
    int held;
    int velocity; /* the force-velocity curve is used */
    Py_ssize_t n, n_rows, n_first, n_steps, n_mono, n_filled;
} Step;

static Py_ssize_t count(Py_buffer *v) { return v->len / v->itemsize; }

static int is_int64(Py_buffer *v) {
    return v->itemsize == 8 && v->format != NULL &&
           (strcmp(v->format, "l") == 0 || strcmp(v->format, "q") == 0);
}

/* "d", or "=d" as numpy names an unaligned array's items (a view into a message's bytes) */
static int is_int32(Py_buffer *v) {
    return v->itemsize == 4 && v->format != NULL && strcmp(v->format, "i") == 0;
}

static int is_float64(Py_buffer *v) {
    return v->itemsize == 8 && v->format != NULL &&
           (strcmp(v->format, "d") == 0 || strcmp(v->format, "=d") == 0);
}

static void Step_dealloc(Step *self) {
    for (int i = 0; i < self->held; i++)
        PyBuffer_Release(&self->bufs[i]);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int refuse(const char *what, const char *need) {
    PyErr_Format(PyExc_ValueError, "%s: %s", what, need);
    return -1;
}

static int Step_init(Step *self, PyObject *args, PyObject *kwds) {
    PyObject *arr[N_BUFS];
    int velocity = 1;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOOOOOOOOOOOp", &arr[0], &arr[1], &arr[2], &arr[3],
                          &arr[4], &arr[5], &arr[6], &arr[7], &arr[8], &arr[9], &arr[10],
                          &arr[11], &arr[12], &arr[13], &arr[14], &arr[15], &arr[16], &arr[17],
                          &arr[18], &arr[19], &arr[20], &arr[21], &arr[22], &arr[23], &velocity))
        return -1;
    for (int i = 0; i < self->held; i++)
        PyBuffer_Release(&self->bufs[i]);
    self->held = 0;
    self->velocity = velocity;
    for (int i = 0; i < N_BUFS; i++) {
        const int written = i >= XE;
        if (PyObject_GetBuffer(arr[i], &self->bufs[i],
                               PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (written ? PyBUF_WRITABLE : 0)) < 0)
            return -1;
        self->held++;
        /* the sparse product's column indices as int32: its tables are most of the memory
           a sample reads, and they come cold from memory after the node's sleep */
        const int ints = i == VARIABLES || i == OUT || i == PA || i == PB || i == INDPTR ||
                         i == ROWS;
        if (i == INDICES ? !is_int32(&self->bufs[i])
                         : ints ? !is_int64(&self->bufs[i]) : !is_float64(&self->bufs[i]))
            return refuse(names[i], i == INDICES ? "a contiguous int32 array"
                                    : ints ? "a contiguous int64 array" : "a contiguous float64 array");
    }
    Py_buffer *b = self->bufs;
    const Py_ssize_t n = self->n = count(&b[LTS]);
    self->n_rows = count(&b[INDPTR]) - 1;
    self->n_first = count(&b[VARIABLES]);
    self->n_steps = count(&b[OUT]);
    self->n_mono = count(&b[MONO]);
    if (count(&b[CENTER]) != NJ || count(&b[INV_HALF]) != NJ || count(&b[XE]) != NJ + 1)
        return refuse("center, inv_half, xe", "20, 20 and 21 values");
    for (int i = INV_L0; i <= F0; i++)
        if (count(&b[i]) != n)
            return refuse(names[i], "one value per muscle (as lts)");
    if (count(&b[I_V]) != n || count(&b[UNIT]) != n || count(&b[I_A]) != NJ * n)
        return refuse("v, unit, a", "n, n and 20 n values");
    if (count(&b[RHS_U]) != NJ || count(&b[RHS_L]) != NJ)
        return refuse("rhs_u, rhs_l", "20 values each");
    if (self->n_rows != n + n * NJ || count(&b[BUF]) != self->n_rows)
        return refuse("indptr, buf", "the rows [L (n); R (n, 20) flat]");
    if (count(&b[PA]) != self->n_steps || count(&b[PB]) != self->n_steps)
        return refuse("out, pa, pb", "one entry per product");
    /* every index in range once, here: the per-sample loops then do not check */
    const int64_t *ip = b[INDPTR].buf;
    const int32_t *ix = b[INDICES].buf;
    const Py_ssize_t nnz = count(&b[DATA]);
    if (ip[0] != 0 || ip[self->n_rows] != nnz || count(&b[INDICES]) != nnz)
        return refuse("indptr", "a CSR row pointer over data and indices");
    for (Py_ssize_t r = 0; r < self->n_rows; r++)
        if (ip[r + 1] < ip[r])
            return refuse("indptr", "non-decreasing");
    for (Py_ssize_t k = 0; k < nnz; k++)
        if (ix[k] < 0 || ix[k] >= self->n_mono)
            return refuse("indices", "monomials in range");
    /* rows: the non-empty rows, each once, longest first (the product's interleaving) */
    const int64_t *rows = b[ROWS].buf;
    self->n_filled = count(&b[ROWS]);
    Py_ssize_t filled = 0;
    for (Py_ssize_t r = 0; r < self->n_rows; r++)
        filled += ip[r + 1] > ip[r];
    if (self->n_filled != filled)
        return refuse("rows", "every non-empty row once");
    for (Py_ssize_t k = 0; k < self->n_filled; k++) {
        const int64_t r = rows[k];
        if (r < 0 || r >= self->n_rows || ip[r + 1] == ip[r] ||
            (k && ip[r + 1] - ip[r] > ip[rows[k - 1] + 1] - ip[rows[k - 1]]))
            return refuse("rows", "every non-empty row once, longest first");
    }
    const int64_t *var = b[VARIABLES].buf, *out = b[OUT].buf, *pa = b[PA].buf, *pb = b[PB].buf;
    if (1 + self->n_first > self->n_mono)
        return refuse("variables", "degree-1 monomials after the constant");
    for (Py_ssize_t k = 0; k < self->n_first; k++)
        if (var[k] < 1 || var[k] > NJ)
            return refuse("variables", "indices of x in [1, x]");
    for (Py_ssize_t s = 0; s < self->n_steps; s++)
        if (out[s] <= self->n_first || out[s] >= self->n_mono || pa[s] < 0 || pa[s] >= out[s] ||
            pb[s] < 0 || pb[s] >= out[s])
            return refuse("out, pa, pb", "products of monomials made before them");
    return 0;
}

static PyObject *Step_problem(Step *self, PyObject *const *args, Py_ssize_t nargs) {
    if (!bound_call(self->held, N_BUFS, "Step", nargs, 3, "problem(q, qd, tau)"))
        return NULL;
    Py_buffer in[3];
    static const char *what[] = {"q", "qd", "tau"};
    for (int k = 0; k < 3; k++) {
        if (get_vector(args[k], NJ, &in[k], what[k], 0) < 0) {
            while (k--)
                PyBuffer_Release(&in[k]);
            return NULL;
        }
    }
    double q[NJ], qd[NJ], tau[NJ];
    memcpy(q, in[0].buf, sizeof q);
    memcpy(qd, in[1].buf, sizeof qd);
    memcpy(tau, in[2].buf, sizeof tau);
    for (int k = 0; k < 3; k++)
        PyBuffer_Release(&in[k]);

    Py_buffer *b = self->bufs;
    const Py_ssize_t n = self->n;
    const double *center = b[CENTER].buf, *inv_half = b[INV_HALF].buf;
    double *xe = b[XE].buf, *mono = b[MONO].buf, *buf = b[BUF].buf;
    xe[0] = 1.0;
    for (int j = 0; j < NJ; j++) { /* np.clip: max with -1, then min with 1 */
        double x = (q[j] - center[j]) * inv_half[j];
        x = x < -1.0 ? -1.0 : x;
        xe[j + 1] = x > 1.0 ? 1.0 : x;
    }
    const int64_t *var = b[VARIABLES].buf, *out = b[OUT].buf, *pa = b[PA].buf, *pb = b[PB].buf;
    mono[0] = 1.0;
    for (Py_ssize_t k = 0; k < self->n_first; k++)
        mono[1 + k] = xe[var[k]];
    for (Py_ssize_t s = 0; s < self->n_steps; s++)
        mono[out[s]] = mono[pa[s]] * mono[pb[s]];
    const int64_t *ip = b[INDPTR].buf;
    const int32_t *ix = b[INDICES].buf;
    const double *data = b[DATA].buf;
    /* Each row as scipy's csr_matvec sums it (0, then each term in order), four rows at a
       time: one row's sum is a chain of dependent additions, four chains keep the adder
       in flight (21 -> 15.5 us for the shipped model, back to back; the same sums). Rows of
       similar lengths go together (rows: longest first);
       one row's terms past the shortest of its group's are summed after. */
    memset(buf, 0, self->n_rows * sizeof(double));
    const int64_t *rows = b[ROWS].buf;
    Py_ssize_t g = 0;
    for (; g + 4 <= self->n_filled; g += 4) {
        const int64_t *r = rows + g;
        const int64_t k0 = ip[r[0]], k1 = ip[r[1]], k2 = ip[r[2]], k3 = ip[r[3]];
        const int64_t common = ip[r[3] + 1] - k3; /* the shortest of the four */
        double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
        for (int64_t t = 0; t < common; t++) {
            s0 += data[k0 + t] * mono[ix[k0 + t]];
            s1 += data[k1 + t] * mono[ix[k1 + t]];
            s2 += data[k2 + t] * mono[ix[k2 + t]];
            s3 += data[k3 + t] * mono[ix[k3 + t]];
        }
        for (int64_t k = k0 + common; k < ip[r[0] + 1]; k++)
            s0 += data[k] * mono[ix[k]];
        for (int64_t k = k1 + common; k < ip[r[1] + 1]; k++)
            s1 += data[k] * mono[ix[k]];
        for (int64_t k = k2 + common; k < ip[r[2] + 1]; k++)
            s2 += data[k] * mono[ix[k]];
        buf[r[0]] = s0;
        buf[r[1]] = s1;
        buf[r[2]] = s2;
        buf[r[3]] = s3;
    }
    for (; g < self->n_filled; g++) {
        const int64_t r = rows[g];
        double sum = 0.0;
        for (int64_t k = ip[r]; k < ip[r + 1]; k++)
            sum += data[k] * mono[ix[k]];
        buf[r] = sum;
    }
    const double *L = buf, *R = buf + n;
    const double *lts = b[LTS].buf, *inv_l0 = b[INV_L0].buf, *v_scale = b[V_SCALE].buf;
    const double *f0_d1 = b[F0_D1].buf, *f0_d4 = b[F0_D4].buf, *f0 = b[F0].buf;
    double *V = b[I_V].buf, *unit = b[UNIT].buf, *A = b[I_A].buf;
    for (Py_ssize_t i = 0; i < n; i++) {
        double v = 0.0; /* V = -(R qd) */
        for (int j = 0; j < NJ; j++)
            v += R[i * NJ + j] * qd[j];
        V[i] = -v;
        double ln = L[i] - lts[i]; /* the fibre's normalised length, rigid tendon */
        ln = ln < 1e-6 ? 1e-6 : ln;
        ln = ln * inv_l0[i];
        double fl = 0.0;
        for (int c = 0; c < 3; c++) {
            double g = (ln - B2[c]) / (B3[c] + B4[c] * ln);
            fl += exp(-0.5 * (g * g)) * B1[c];
        }
        double u;
        if (self->velocity)
            u = fl * (f0_d1[i] * asinh(v_scale[i] * V[i] + D3) + f0_d4[i]);
        else
            u = f0[i] * fl;
        unit[i] = u;
        for (int j = 0; j < NJ; j++)
            A[j * n + i] = R[i * NJ + j] * u;
    }
    memcpy(b[RHS_U].buf, tau, sizeof tau);
    memcpy(b[RHS_L].buf, tau, sizeof tau);
    Py_RETURN_NONE;
}

static PyObject *Step_finish(Step *self, PyObject *const *args, Py_ssize_t nargs) {
    if (!bound_call(self->held, N_BUFS, "Step", nargs, 4,
                    "finish(x, activations, forces, reserves)"))
        return NULL;
    const Py_ssize_t n = self->n;
    Py_buffer xb, ob[3];
    if (get_vector(args[0], n, &xb, "x", PyBUF_WRITABLE) < 0)
        return NULL;
    static const char *what[] = {"activations", "forces", "reserves"};
    for (int k = 0; k < 3; k++) {
        if (get_vector(args[1 + k], k == 2 ? NJ : n, &ob[k], what[k], PyBUF_WRITABLE) < 0) {
            while (k--)
                PyBuffer_Release(&ob[k]);
            PyBuffer_Release(&xb);
            return NULL;
        }
    }
    Py_buffer *b = self->bufs;
    double *x = xb.buf; /* daqp's own array: aligned */
    const double *A = b[I_A].buf, *unit = b[UNIT].buf, *rhs = b[RHS_U].buf;
    double m = -INFINITY;
    for (Py_ssize_t i = 0; i < n; i++) {
        double a = x[i];
        a = a < 0.0 ? 0.0 : a;
        a = a > 1.0 ? 1.0 : a;
        x[i] = a;
        m = a > m ? a : m;
        const double f = a * unit[i];
        memcpy((char *)ob[1].buf + i * 8, &f, 8);
    }
    memcpy(ob[0].buf, x, n * 8);
    for (int j = 0; j < NJ; j++) {
        double s = 0.0;
        for (Py_ssize_t i = 0; i < n; i++)
            s += A[j * n + i] * x[i];
        const double r = rhs[j] - s;
        memcpy((char *)ob[2].buf + j * 8, &r, 8);
    }
    for (int k = 0; k < 3; k++)
        PyBuffer_Release(&ob[k]);
    PyBuffer_Release(&xb);
    return PyFloat_FromDouble(m);
}

static PyMethodDef Step_methods[] = {
    {"problem", (PyCFunction)(void (*)(void))Step_problem, METH_FASTCALL,
     "R, L, V, unit forces, A and the right-hand sides of one sample"},
    {"finish", (PyCFunction)(void (*)(void))Step_finish, METH_FASTCALL,
     "x clipped; activations, forces, reserves written; returns max(x)"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject StepType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "forearm_dynamics.muscles._muscle_step.Step",
    .tp_doc = "The muscle node's per-sample arithmetic around the QP, bound to its arrays.",
    .tp_basicsize = sizeof(Step),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Step_init,
    .tp_dealloc = (destructor)Step_dealloc,
    .tp_methods = Step_methods,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_muscle_step", "See muscle_step.py.", -1, NULL, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__muscle_step(void) {
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
