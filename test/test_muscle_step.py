"""The muscle node's compiled step (muscles/muscle_step.py, _muscle_step.c) against numpy's
way, the reference it replaces: whole movements through StaticOptimizer.solve_sample_into with
and without it (reserves in use, postures outside the fit box, with and without the
force-velocity), outputs in a message's unaligned bytes, what it must refuse, and what it
leaves to numpy (passive forces, arrays it cannot take)."""

from __future__ import annotations

import numpy as np
import pytest

from forearm_dynamics import movement_library
from forearm_dynamics.muscles import StaticOptimizer, muscle_step

pytestmark = pytest.mark.unit

NJ = 20


def _outputs(n: int, unaligned: bool = False):
    """(activations, forces, reserves); unaligned: float64 views 4 bytes into one buffer, as
    the fields of a CDR message are."""
    if not unaligned:
        return np.empty(n), np.empty(n), np.empty(NJ)
    raw = np.zeros(8 * (2 * n + NJ) + 4, np.uint8)
    v = np.frombuffer(raw.data, np.float64, 2 * n + NJ, offset=4)
    assert not v.flags.aligned
    return v[:n], v[n: 2 * n], v[2 * n:]


def _numpy_way(so: StaticOptimizer, geo) -> None:
    so._step = (geo, None)  # what solve_sample_into does without the extension


def test_the_compiled_step_is_built(mm) -> None:
    """setup.py builds it wherever a C compiler is (every machine this suite runs on); a
    missing one would leave muscle_node on numpy's way, ~80 µs a sample slower paced (docs)."""
    assert muscle_step.available()
    so, geo = StaticOptimizer(mm), mm.geometry_outputs()
    z = np.zeros(NJ)
    so.solve_sample_into(z, z, z, geo, *_outputs(mm.n))
    assert so._step[0] is geo and so._step[1] is not None


def _samples(arm, ids, scale=1.0, step=2):
    for i in ids:
        mv = movement_library()[i]
        q, qd, qdd = mv.evaluate(mv.sample_times(1000))
        yield q[::step], qd[::step], scale * arm.inverse_dynamics(q, qd, qdd)[::step]


@pytest.mark.parametrize("case", ["library", "reserves", "outside_box", "no_velocity"])
def test_whole_movements_give_numpys_answers(mm, arm, case) -> None:
    """Sample after sample (each warm-starts the next), the compiled path and numpy's write
    the same moment arms and lengths to the bit (the same products and sums in the same
    order), and the path velocities, the QP's matrix, activations, forces and reserves within
    1e-12 of each quantity's range (libm's exp and asinh, BLAS's sums; measured ≤ 1e-15); the
    same exit flags and saturation. Outputs in unaligned bytes, as the node's messages."""
    velocity = case != "no_velocity"
    fast, ref = StaticOptimizer(mm, velocity=velocity), StaticOptimizer(mm, velocity=velocity)
    gf, gr = mm.geometry_outputs(), mm.geometry_outputs()
    _numpy_way(ref, gr)
    of, orf = _outputs(mm.n, unaligned=True), _outputs(mm.n)
    got = {k: [] for k in ("R", "L", "V", "A", "a", "f", "r")}
    want = {k: [] for k in got}
    ids, scale = ([1, 24, 40, 62], 1.0) if case != "reserves" else ([13, 33], 3.0)
    rng = np.random.default_rng(5)
    flags = []
    for q, qd, tau in _samples(arm, ids, scale):
        if case == "outside_box":  # postures beyond the fit box: the clip holds them at its edge
            q = mm.surrogate.center + mm.surrogate.half * rng.uniform(-1.4, 1.4, q.shape)
        for k in range(len(q)):
            rf = fast.solve_sample_into(q[k], qd[k], tau[k], gf, *of)
            rr = ref.solve_sample_into(q[k], qd[k], tau[k], gr, *orf)
            flags.append(rf[:2] == rr[:2])
            for d, g, o, so in ((got, gf, of, fast), (want, gr, orf, ref)):
                for key, x in zip(d, (g[0], g[1], g[2], so._A, *o)):
                    d[key].append(np.array(x))
    assert fast._step[1] is not None and ref._step[1] is None
    assert all(flags)
    for key, values in got.items():
        a, b = np.array(values), np.array(want[key])
        if key in ("R", "L"):
            assert np.array_equal(a, b), key
        else:
            span = b.max() - b.min()
            assert span > 0, key
            assert np.abs(a - b).max() <= 1e-12 * span, (key, np.abs(a - b).max() / span)
    if case == "reserves":
        assert np.abs(np.array(want["r"])).max() > 0.1  # the reserves carried something
    if case == "outside_box":
        assert not mm.surrogate.in_box(q).all()


def test_the_kernel_refuses_what_it_cannot_take_and_writes_nothing(mm) -> None:
    """problem() and finish() check every argument before they write; the tables are checked
    once, when bound, each refusal naming what is wrong."""
    so, geo = StaticOptimizer(mm), mm.geometry_outputs()
    z = np.zeros(NJ)
    so.solve_sample_into(z, z, z, geo, *_outputs(mm.n))
    step = so._step[1]
    before = [np.array(x) for x in (geo[0], geo[1], geo[2], so._A)]
    for bad, word in (((z.astype(np.float32), z, z), "^q:"), ((z, np.zeros(19), z), "^qd:"),
                      ((z, z, np.zeros(NJ + 1)), "^tau:")):
        with pytest.raises((ValueError, BufferError), match=word):
            step.problem(*bad)
    with pytest.raises(TypeError):
        step.problem(z, z)
    x = np.full(mm.n, 0.5)
    a, f, _ = _outputs(mm.n)
    a.fill(7.0)
    with pytest.raises(ValueError, match="^reserves:"):
        step.finish(x, a, f, np.zeros(NJ + 1))
    assert np.all(x == 0.5) and np.all(a == 7.0)  # nothing clipped, nothing written
    for b0, b1 in zip(before, (geo[0], geo[1], geo[2], so._A)):
        assert np.array_equal(b0, b1)
    # the tables: an index out of range, rows not longest first, a wrong type
    s = mm.surrogate
    args = {"surrogate": s, "unit": so._unit, "geo_buffer": s.output_buffer(geo[0], geo[1]),
            "V": geo[2], "A": so._A, "rhs_u": so._rhs_u, "rhs_l": so._rhs_l}
    assert muscle_step.bind(**args) is not None
    full = s._full
    try:
        bad_ix = full[3].copy()
        bad_ix[7] = s.n_monomials
        s._full = (*full[:3], bad_ix, full[4])
        with pytest.raises(ValueError, match="^indices:"):
            muscle_step.bind(**args)
        s._full = (*full[:4], full[4].astype(np.float32))
        with pytest.raises(ValueError, match="^data:"):
            muscle_step.bind(**args)
    finally:
        s._full = full
    length = np.diff(full[2])
    shortest_first = np.argsort(length, kind="stable")[-np.count_nonzero(length):]
    with pytest.raises(ValueError, match="^rows:"):
        muscle_step.bind(**args, rows=shortest_first)


def test_what_it_does_not_cover_runs_numpys_way(mm, arm) -> None:
    """Passive fibre forces (not in the kernel), geometry arrays other than
    geometry_outputs()'s and inputs it cannot take (float32, not contiguous): numpy's way, bit
    for bit solve_into's answer; outputs it cannot take (not contiguous): numpy writes them,
    from the kernel's problem (within 1e-12 of the range, as above)."""
    q, qd, tau = next(_samples(arm, [40], step=25))
    cases = {
        "passive": (StaticOptimizer(mm, passive=True), mm.geometry_outputs(), lambda x: x,
                    _outputs(mm.n)),
        "foreign geometry": (StaticOptimizer(mm), (np.zeros((mm.n, NJ)), np.zeros(mm.n),
                                                   np.zeros(mm.n)), lambda x: x, _outputs(mm.n)),
        "float32 input": (StaticOptimizer(mm), mm.geometry_outputs(),
                          lambda x: x.astype(np.float32), _outputs(mm.n)),
        "strided input": (StaticOptimizer(mm), mm.geometry_outputs(),
                          lambda x: np.repeat(x, 2)[::2], _outputs(mm.n)),
        "strided output": (StaticOptimizer(mm), mm.geometry_outputs(), lambda x: x,
                           tuple(np.empty(2 * len(o))[::2] for o in _outputs(mm.n))),
    }
    for name, (so, geo, conv, outs) in cases.items():
        ref = StaticOptimizer(mm, passive=so.passive)
        for k in range(len(q)):
            qk, qdk, tauk = conv(q[k]), conv(qd[k]), conv(tau[k])
            got = so.solve_sample_into(qk, qdk, tauk, geo, *outs)
            R, L, V = mm.geometry(qk.astype(float), qdk.astype(float))
            want = _outputs(mm.n)
            exp = ref.solve_into(R, L, V, tauk.astype(float), *want)
            assert got[:2] == exp[:2], name
            for g, w in zip(outs, want):
                if name == "strided output":
                    assert np.abs(g - w).max() <= 1e-12 * max(np.ptp(w), 1.0), name
                else:
                    assert np.array_equal(g, w), name
        covered = so._step[1] is not None
        assert covered == (name in ("float32 input", "strided input", "strided output")), name
