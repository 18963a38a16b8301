/* noise.py's three evaluations (white, velocity, position) on the arrays a Store is bound
 * to: the same operations in the same order as Python's, so the estimates are the same
 * numbers to the bit (test_noise_step.py). Where numpy sums (a block's stamps, np.add.reduce)
 * its pairwise order is followed; the weighted sums are in order on both sides
 * (noise._weighted_rows). Built with -ffp-contract=off, as _noise_step.c. */
#include "_noise_step.h"

/* noise.py's divided_difference_weights on m times; 0 for a repeated time (Python's
   ZeroDivisionError: no difference across it) */
static int weights(const double *t, int m, double *w, double *sw) {
    for (int i = 0; i < m; i++) {
        double p = 1.0;
        for (int j = 0; j < m; j++)
            if (j != i)
                p *= t[i] - t[j];
        if (p == 0.0)
            return 0;
        w[i] = 1.0 / p;
    }
    double s = 0.0;
    for (int i = 0; i < m; i++)
        s += w[i] * w[i];
    *sw = s;
    return 1;
}

/* noise._weighted_rows for joint j: sum_i w[i] rows[i][j] over m rows of n, in order */
static double weighted(const double *w, int m, const double *rows, Py_ssize_t n, Py_ssize_t j) {
    double z = w[0] * rows[j];
    for (int i = 1; i < m; i++)
        z += w[i] * rows[i * n + j];
    return z;
}

/* noise.py's _white_evaluation: the third (divided) difference of the white window. */
void white_evaluation(Store *self, int64_t *c, const double *r, long long dense) {
    static const double d3[4] = {-1.0, 3.0, -3.0, 1.0};
    const Py_ssize_t n = self->n;
    const double *ring = self->bufs[B_WRING].buf, *t = self->bufs[B_WT].buf;
    double *ms = self->bufs[B_MSW].buf;
    double w[4], scale;
    if (c[SAME] >= 3) { /* uniform: (-1, 3, -3, 1) rolled so that the newest sample has 1 */
        const long long shift = pymod(c[WCOUNT] - 1, 4) + 1;
        for (int i = 0; i < 4; i++)
            w[i] = d3[pymod(i - shift, 4)];
        scale = 1.0 / 20.0;
    } else { /* the divided difference on the real times: none across a repeated stamp */
        double sw;
        if (!weights(t, 4, w, &sw))
            return;
        scale = 1.0 / sw;
    }
    const long long k = ++c[WEVALS];
    const double dt = r[DT];
    const double a = fmin(1.0, fmax(1.0 / (double)k, (double)dense * dt / self->tau_s));
    for (Py_ssize_t j = 0; j < n; j++) {
        double z = weighted(w, 4, ring, n, j);
        z *= z;
        z *= scale;
        z -= ms[j];
        z *= a;
        ms[j] += z;
    }
}

/* noise.py's _accumulate of self->z into ms (the k-th evaluation, step_s apart): a running
   mean, then exponential (tau_s); winsorised at clip_sigmas unless clipped clip_run times in a
   row (nclip counts them per joint). */
static void accumulate(Store *self, double *ms, int64_t *nclip, long long k, double step_s) {
    const Py_ssize_t n = self->n;
    double *z = self->z;
    if (k > self->min_evaluations) {
        const double c2 = self->clip_sigmas * self->clip_sigmas;
        int any = 0;
        for (Py_ssize_t j = 0; j < n; j++)
            any |= z[j] > ms[j] * c2;
        if (any) {
            for (Py_ssize_t j = 0; j < n; j++) {
                const int over = z[j] > ms[j] * c2;
                nclip[j] = (nclip[j] + 1) * over;
                if (nclip[j] < self->clip_run && over)
                    z[j] = ms[j] * c2;
            }
        } else {
            memset(nclip, 0, (size_t)n * sizeof(int64_t));
        }
    }
    const double a = fmin(1.0, fmax(1.0 / (double)k, step_s / self->tau_s));
    for (Py_ssize_t j = 0; j < n; j++) {
        double d = z[j] - ms[j];
        d *= a;
        ms[j] += d;
    }
}

/* noise.py's _velocity_evaluation: v0 - v1 - rho (v1 - v2), accumulated. */
void velocity_evaluation(Store *self, int64_t *c, long long dense) {
    const Py_ssize_t n = self->n;
    const double *ring = self->bufs[B_VRING].buf, *t = self->bufs[B_VT].buf;
    double *ms = self->bufs[B_MSV].buf, *z = self->z;
    int64_t *nclip = self->bufs[B_NCLIPV].buf;
    const long long h = c[VCOUNT] % 3, h1 = pymod(h - 1, 3), h2 = pymod(h - 2, 3);
    const double t0 = t[h], t1 = t[h1], t2 = t[h2];
    if (!(t0 > t1 && t1 > t2))
        return;
    const double rho = (t0 - t1) / (t1 - t2), u = 1.0 + rho;
    const double norm = 1.0 / (1.0 + u * u + rho * rho);
    const double *v0 = ring + h * n, *v1 = ring + h1 * n, *v2 = ring + h2 * n;
    for (Py_ssize_t j = 0; j < n; j++) {
        double d = (v0[j] - v1[j]) - (v1[j] - v2[j]) * rho;
        d *= d;
        z[j] = d * norm;
    }
    accumulate(self, ms, nclip, ++c[VEVALS], (double)dense * (t0 - t1));
}

/* numpy's sum of n contiguous doubles (pairwise, 8 accumulators: np.add.reduce), which
   noise.py's block means and variances get, to the bit */
static double pairwise_sum(const double *a, Py_ssize_t n) {
    if (n < 8) {
        double res = 0.0;
        for (Py_ssize_t i = 0; i < n; i++)
            res += a[i];
        return res;
    }
    if (n <= 128) {
        double r[8];
        Py_ssize_t i;
        for (int j = 0; j < 8; j++)
            r[j] = a[j];
        for (i = 8; i < n - (n % 8); i += 8)
            for (int j = 0; j < 8; j++)
                r[j] += a[i + j];
        double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; i++)
            res += a[i];
        return res;
    }
    Py_ssize_t n2 = n / 2;
    n2 -= n2 % 8;
    return pairwise_sum(a, n2) + pairwise_sum(a + n2, n - n2);
}

/* noise.py's _position_evaluation (and _comparable): the fifth divided difference of the
   block means. Returns 0 having done it (or skipped an irregular window, as Python does),
   1 to leave it to Python (a ring of other than BLOCKS blocks, repeated times). */
int position_evaluation(Store *self, int64_t *c, const double *r) {
    const Py_ssize_t n = self->n;
    const long long cap = c[CAP], s = c[STRIDE];
    if (s < 1 || cap != BLOCKS * s)
        return 1;
    const long long h = pymod(c[COUNT] - 1, cap);
    const double *x = (const double *)self->bufs[B_RAW].buf + (h + 1) * n;
    const double *tw = (const double *)self->bufs[B_RAWT].buf + (h + 1);
    double *ms = self->bufs[B_MS].buf, *z = self->z, *sums = self->z + n;
    double w[BLOCKS], sw;
    if (c[SAME] > cap) { /* uniform stamps: the weights of that spacing */
        double span[BLOCKS];
        for (int i = 0; i < BLOCKS; i++)
            span[i] = (double)((i - (BLOCKS - 1)) * s * c[LAST_D]) * 1e-9;
        if (!weights(span, BLOCKS, w, &sw))
            return 1;
    } else { /* jittered: the weights of the blocks' mean times, if the blocks compare */
        double tm[BLOCKS];
        for (int b = 0; b < BLOCKS; b++)
            tm[b] = pairwise_sum(tw + b * s, s) / (double)s;
        if (s >= self->min_block) {
            const double span = tw[cap - 1] - tw[0];
            int ok = !(span > self->window_stretch * (double)(cap - 1) * r[DT]);
            if (ok) {
                double lo = INFINITY, hi = -INFINITY;
                double *d = sums + BLOCKS * n; /* a block's squared deviations */
                for (int b = 0; b < BLOCKS; b++) {
                    for (long long i = 0; i < s; i++) {
                        const double e = tw[b * s + i] - tm[b];
                        d[i] = e * e;
                    }
                    const double v = pairwise_sum(d, s) / (double)s;
                    lo = fmin(lo, v);
                    hi = fmax(hi, v);
                }
                ok = hi <= self->block_spread_ratio * lo;
            }
            if (!ok) {
                c[IRREGULAR]++;
                return 0;
            }
        }
        if (!weights(tm, BLOCKS, w, &sw))
            return 1;
    }
    /* the blocks' sums (summed in order, as numpy sums a middle axis), weighted in order */
    for (int b = 0; b < BLOCKS; b++) {
        const double *xb = x + b * s * n;
        double *sb = sums + b * n;
        memcpy(sb, xb, (size_t)n * sizeof(double));
        for (long long i = 1; i < s; i++)
            for (Py_ssize_t j = 0; j < n; j++)
                sb[j] += xb[i * n + j];
    }
    const double scale = 1.0 / ((double)s * sw);
    for (Py_ssize_t j = 0; j < n; j++) {
        double v = weighted(w, BLOCKS, sums, n, j);
        v *= v;
        z[j] = v * scale;
    }
    accumulate(self, ms, self->bufs[B_NCLIP].buf, ++c[PEVALS], (double)c[EVERY] * r[DT]);
    return 0;
}

