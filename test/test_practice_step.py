"""The practice filter's compiled step (estimation/practice_step.py, _practice_step.c) against
numpy's way, the reference it replaces: whole positions-only streams through the Kalman
filter with and without it (uniform, jittered, dropped samples, a restart, a discontinuity,
an outlier the gate holds, a new rate, a share below 1), samples that go either way, copies
and pickles, and what it must refuse."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from forearm_dynamics.estimation import make_estimator, practice_step
from forearm_dynamics.estimation.practice_blend import PracticeBlend
from forearm_dynamics.estimation.practice_fir import PracticeFIR

pytestmark = pytest.mark.unit

N = 6
#: the two paths differ only where numpy hands a sum to BLAS (the FIR's taps, the practice's
#: kernel; practice_step.py): q̈ within this many times the stream's largest |q̈|
REL = 1e-12


def test_the_compiled_step_is_built_and_used() -> None:
    """setup.py builds it with the Kalman step; a noisy positions-only stream uses it."""
    assert practice_step.available()
    est = make_estimator("kalman", N)
    t, q = positions(100.0, 3.0)
    for k in range(len(t)):
        est.update(int(t[k]), q[k], None)
    assert est._pstep is not None
    assert est.practice_filter_weight().max() == 1.0  # the filter is on: the call did work


def positions(rate: float, seconds: float, seed: int = 0, jitter: float = 0.0,
              drop: float = 0.0, gaps: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (ns) and positions (rad) of slow movements with white and coloured noise (the
    practice filter's joints: coloured noise above the band), jittered and thinned."""
    rng = np.random.default_rng(seed)
    n = int(seconds * rate)
    st = (np.arange(n) / rate * 1e9).astype(np.int64)
    if jitter:
        st += (rng.uniform(-jitter, jitter, n) * 1e9 / rate).astype(np.int64)
    t = st * 1e-9  # the positions at the stamps: jitter is not noise
    q = 0.4 * np.sin(2 * np.pi * (0.3 + 0.15 * np.arange(N)) * t[:, None] + np.arange(N))
    q += np.convolve(rng.normal(0.0, 0.01, n + 20), np.ones(20) / 20, "same")[:n, None]
    q += rng.normal(0.0, 0.003, q.shape)
    q[:, -1] = 0.2 * np.sin(2 * np.pi * 0.4 * t)  # exact input: the model's q̈ (not the rule's)
    keep = rng.random(n) >= drop
    if gaps:  # 0.15-0.35 s lost: more than the FIR's span at 100 Hz, filled on the line
        for start, length in ((300, 15), (450, 28), (600, 35)):
            keep[start:start + length] = False
    keep[:3] = True
    return st[keep], q[keep]


def run(t: np.ndarray, q: np.ndarray, compiled: bool, settings: dict | None = None,
        events=None, est=None):
    """q̈ outputs (len(t), N) of the default Kalman filter, with or without the compiled
    step; events: {sample index: callable(est)} run before that sample."""
    est = est or make_estimator("kalman", N, settings or {})
    if not compiled:
        est.python_practice()
    out = np.zeros((len(t), N))
    for k in range(len(t)):
        if events and k in events:
            events[k](est)
        est.update(int(t[k]), q[k], None)
        out[k] = est.qdd
    return out, est


def same_state(a, b) -> None:
    """The counters to the number, the floats to rounding."""
    fa, fb = a._pfir, b._pfir
    assert (fa.count, fa.K, int(fa._c[1])) == (fb.count, fb.K, int(fb._c[1]))
    assert a._pblend.evaluations == b._pblend.evaluations
    assert a._pblend._win.count == b._pblend._win.count
    np.testing.assert_array_equal(fa._ring, fb._ring)
    np.testing.assert_array_equal(a._pf_w, b._pf_w)
    np.testing.assert_allclose(a._pblend._s, b._pblend._s, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(a._pblend.disagreement, b._pblend.disagreement, rtol=1e-9, atol=1e-12)


def close(a: np.ndarray, b: np.ndarray) -> None:
    scale = np.abs(b).max()
    assert scale > 0.0
    assert np.abs(a - b).max() <= REL * scale, np.abs(a - b).max() / scale


def restart(est) -> None:
    est.reset()


STREAMS = {
    "100hz": {"rate": 100.0, "seconds": 6.0},
    "jittered_dropped": {"rate": 100.0, "seconds": 6.0, "jitter": 0.2, "drop": 0.05},
    "1khz": {"rate": 1000.0, "seconds": 3.0, "jitter": 0.1, "drop": 0.01},
    "60hz_dropouts": {"rate": 60.0, "seconds": 8.0, "drop": 0.1},
    "100hz_gaps": {"rate": 100.0, "seconds": 8.0, "gaps": True},
}


@pytest.mark.parametrize("name", sorted(STREAMS))
def test_whole_streams_are_numpys(name) -> None:
    s = STREAMS[name]
    t, q = positions(s["rate"], s["seconds"], 1, s.get("jitter", 0.0), s.get("drop", 0.0),
                     s.get("gaps", False))
    a, ea = run(t, q, True)
    b, eb = run(t, q, False)
    assert ea._pstep is not None and eb._pstep is None
    assert ea.practice_filter_weight().max() == 1.0
    assert ea.practice_filter_weight()[-1] == 0.0  # the exact joint keeps the model
    close(a, b)
    same_state(ea, eb)


def test_a_restart_a_jump_an_outlier_and_a_new_rate() -> None:
    """A reset (the ring refills: the model's output), a step of 0.5 rad (the gate's
    discontinuity), a 20° single-sample spike (held, then restored or not) and a new rate
    (100 -> 50 Hz: new rings, the step bound again)."""
    t, q = positions(100.0, 12.0, 2)
    q = q.copy()
    q[500:] += 0.5
    q[300, 2] += np.radians(20.0)
    t = t.copy()
    t[800:] = t[800] + (t[800:] - t[800]) * 2  # 50 Hz from sample 800
    first = []
    events = {200: restart, 790: lambda est: first.append(est._pstep)}
    a, ea = run(t, q, True, events=events)
    b, eb = run(t, q, False, events={200: restart})
    close(a, b)
    same_state(ea, eb)
    assert ea._pfir.dt > 0.015  # configured for the new rate: new rings, bound again
    assert first[0] is not None and ea._pstep is not first[0]
    assert ea._pstep_key[0] is ea._pfir._ring


def test_a_share_below_one_is_numpys() -> None:
    """estimator.practice_filter 0.5: the faded sum's other branch (f * w)."""
    t, q = positions(100.0, 6.0, 3)
    a, ea = run(t, q, True, {"practice_filter": 0.5})
    b, eb = run(t, q, False, {"practice_filter": 0.5})
    assert ea.practice_filter_weight().max() == 0.5
    close(a, b)
    same_state(ea, eb)


def test_samples_may_go_either_way() -> None:
    """Every third sample as a strided view (the compiled call refuses it: numpy's way): the
    counters the two share are the same numbers, so the stream is the compiled one's."""
    t, q = positions(100.0, 6.0, 4)
    wide = np.zeros((len(q), 2 * N))
    wide[:, ::2] = q
    a, ea = run(t, q, True)
    est = make_estimator("kalman", N)
    mixed = np.zeros_like(a)
    for k in range(len(t)):
        est.update(int(t[k]), wide[k, ::2] if k % 3 == 0 else q[k], None)
        mixed[k] = est.qdd
    assert est._pstep is not None
    close(mixed, a)
    same_state(est, ea)


@pytest.mark.parametrize("how", ["copy", "pickle"])
def test_copies_and_pickles_bind_their_own(how) -> None:
    """A copy mid-stream goes on as the original does, and writes nothing into it."""
    t, q = positions(100.0, 6.0, 5)
    half = len(t) // 2
    _, est = run(t[:half], q[:half], True)
    twin = copy.deepcopy(est) if how == "copy" else pickle.loads(pickle.dumps(est))  # noqa: S301
    ring = est._pfir._ring.copy()
    rest_twin, twin = run(t[half:], q[half:], True, est=twin)
    np.testing.assert_array_equal(est._pfir._ring, ring)  # the original untouched
    rest, est = run(t[half:], q[half:], True, est=est)
    np.testing.assert_array_equal(rest_twin, rest)
    assert twin._pstep is not None and twin._pstep is not est._pstep


def bound_parts(n: int = N):
    fir, blend = PracticeFIR(n), PracticeBlend(n, 6.0)
    fir.configure(0.01)
    blend.configure(0.01)
    out = {"pf_w": np.zeros(n), "target": np.ones(n), "use": np.ones(n, bool), "qdd": np.zeros(n)}
    return fir, blend, out


def test_it_refuses_what_it_cannot_take() -> None:
    fir, blend, o = bound_parts()
    step = practice_step.bind(fir, blend, o["pf_w"], o["target"], o["use"], o["qdd"], 1.0, 0.1)
    with pytest.raises(ValueError, match="q: a contiguous float64 array of 6"):
        step.push(0, np.zeros(N + 1))
    with pytest.raises(ValueError, match="contiguous"):  # numpy's message for a strided view
        step.output(0.01, np.zeros(2 * N)[::2])
    with pytest.raises(TypeError, match=r"push\(t_ns, q\)"):
        step.push(0)
    with pytest.raises(ValueError, match="use: a contiguous bool array"):
        practice_step.bind(fir, blend, o["pf_w"], o["target"], np.ones(N), o["qdd"], 1.0, 0.1)
    with pytest.raises(ValueError, match="qdd: a contiguous float64 array of 6"):
        practice_step.bind(fir, blend, o["pf_w"], o["target"], o["use"], np.zeros(N + 1), 1.0, 0.1)
    ro = np.zeros(N)
    ro.setflags(write=False)
    with pytest.raises(ValueError, match="read-only|not writable"):
        practice_step.bind(fir, blend, ro, o["target"], o["use"], o["qdd"], 1.0, 0.1)
    fir._ring = np.zeros((3, N))  # a ring of another span: refused, not read past its end
    with pytest.raises(ValueError, match="ring: a contiguous float64"):
        practice_step.bind(fir, blend, o["pf_w"], o["target"], o["use"], o["qdd"], 1.0, 0.1)
    with pytest.raises(RuntimeError, match="not bound"):
        practice_step.Practice.__new__(practice_step.Practice).push(0, np.zeros(N))


def test_push_fills_dropped_samples_as_python_does() -> None:
    """The ring to the bit, gaps of 0-40 samples (longer than the ring: clamped to its span),
    stamps that round half to even. In a stream the gate restarts after most long gaps."""
    fir, blend, o = bound_parts()
    ref = PracticeFIR(N)
    ref.configure(0.01)
    step = practice_step.bind(fir, blend, o["pf_w"], o["target"], o["use"], o["qdd"], 1.0, 0.1)
    rng = np.random.default_rng(6)
    t = 10**9
    for _ in range(300):
        t += int(rng.choice([10_000_000, 15_000_000, 25_000_000, 10_000_000 * rng.integers(2, 41)]))
        q = rng.standard_normal(N)
        step.push(t, q)
        ref.push(t, q)
        np.testing.assert_array_equal(fir._ring, ref._ring)
        np.testing.assert_array_equal(fir._c, ref._c)
        np.testing.assert_array_equal(fir._last, ref._last)
