"""The Kalman filter's compiled step (estimation/kalman_step.py, _kalman_step.c) against
numpy's way, the reference it replaces: the kernel's two calls alone, then whole streams
through the filter with and without it (velocities or not, noise, an outlier, a jump, a
gap, jittered stamps, a delay, the practice filter), and what it must refuse."""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest

from forearm_dynamics import get_movement
from forearm_dynamics.estimation import kalman_step, make_estimator

pytestmark = pytest.mark.unit

N = 20


def test_the_compiled_step_is_built() -> None:
    """setup.py builds it wherever a C compiler is (every machine this suite runs on); a
    missing one would leave the node on numpy's way, ~55 µs a sample slower (docs)."""
    assert kalman_step.available()
    est = make_estimator("kalman", N)
    assert est._fast is not None


def _arrays(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"x": rng.standard_normal((3, N)), "t3": np.zeros((3, N)), "e": np.zeros((2, N)),
            "kp": rng.random((3, N)), "kv": rng.random((3, N)), "out": np.zeros((3, N)),
            "keep_q": np.zeros(N), "keep_qd": np.zeros(N)}


@pytest.mark.parametrize("vel", [True, False])
def test_the_kernel_is_numpys_arithmetic(vel) -> None:
    """predict_innovate and correct give numpy's numbers: the correction to the bit (the same
    products and sums in the same order), the prediction within one rounding of BLAS's."""
    a = _arrays()
    step = kalman_step.bind(*a.values())
    rng = np.random.default_rng(1)
    q, qd, dt = rng.standard_normal(N), rng.standard_normal(N), 1.7e-3
    x0 = a["x"].copy()
    f = np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    t3 = f @ x0
    emax = step.predict_innovate(q, qd if vel else None, dt)
    np.testing.assert_allclose(a["t3"], t3, rtol=2e-16, atol=1e-300)
    e0 = q - a["t3"][0]
    np.testing.assert_array_equal(a["e"][0], e0)
    if vel:
        np.testing.assert_array_equal(a["e"][1], qd - a["t3"][1])
    else:
        assert not a["e"][1].any()  # untouched
    assert emax == np.abs(e0).max()
    step.correct(vel, q, qd if vel else None, True)
    x = a["kp"] * a["e"][0]
    if vel:
        x += a["kv"] * a["e"][1]
    x += a["t3"]
    np.testing.assert_array_equal(a["x"], x)
    np.testing.assert_array_equal(a["out"], x)
    np.testing.assert_array_equal(a["keep_q"], q)
    assert (a["keep_qd"] == qd).all() if vel else not a["keep_qd"].any()
    a["out"].fill(7.0)
    step.correct(vel, None, None, False)  # no copies asked: none made
    assert (a["out"] == 7.0).all()


def test_the_kernel_refuses_what_it_cannot_take_and_writes_nothing() -> None:
    a = _arrays()
    step = kalman_step.bind(*a.values())
    before = {k: v.copy() for k, v in a.items()}
    good = np.zeros(N)
    for bad in (np.zeros(N, np.float32), np.zeros(N + 1), np.zeros((2, N))[:, 0], [0.0] * N):
        with pytest.raises((ValueError, TypeError, BufferError)):
            step.predict_innovate(bad, None, 1e-3)
        with pytest.raises((ValueError, TypeError, BufferError)):
            step.predict_innovate(good, bad, 1e-3)
        with pytest.raises((ValueError, TypeError, BufferError)):
            step.correct(True, good, bad, True)
    for k, v in a.items():
        np.testing.assert_array_equal(v, before[k], err_msg=k)
    with pytest.raises(ValueError, match="keep_q"):
        kalman_step.Step(*list(a.values())[:6], np.zeros(N + 1), np.zeros(N))
    with pytest.raises(ValueError, match="x"):
        kalman_step.Step(np.zeros((3, N), np.float32), *list(a.values())[1:])
    with pytest.raises(ValueError, match="t3"):
        kalman_step.Step(a["x"], a["t3"].T.copy(), *list(a.values())[2:])
    frozen = np.zeros((3, N))
    frozen.flags.writeable = False
    with pytest.raises((ValueError, BufferError)):
        kalman_step.Step(frozen, *list(a.values())[1:])
    unbound = kalman_step.Step.__new__(kalman_step.Step)
    with pytest.raises(RuntimeError, match="not bound"):
        unbound.predict_innovate(good, None, 1e-3)


def _stream(mid: int, rate: float, noise_deg: float, seed: int, jitter: float = 0.0):
    mv = get_movement(mid)
    t = mv.sample_times(rate)
    q, qd, _ = mv.evaluate(t)
    rng = np.random.default_rng(seed)
    z = q + math.radians(noise_deg) * rng.standard_normal(q.shape)
    zd = qd + math.radians(5 * noise_deg) * rng.standard_normal(q.shape)
    step = 1e9 / rate
    stamps = 10**9 + np.round(np.arange(len(t)) * step
                              + jitter * step * rng.uniform(-1, 1, len(t))).astype(np.int64)
    k = len(t) // 3
    z[k, 4] += 0.3  # an outlier (one sample)
    z[2 * k:, 6] += 0.8  # a jump that stays
    stamps[k + 40:] += 200_000_000  # a gap
    return stamps, z, zd


CASES = {
    "1kHz_velocities": (1000.0, 0.0, True, {}),
    "1kHz_velocities_noisy_jittered": (1000.0, 0.3, True, {"jitter": 0.2}),
    "1kHz_positions_noisy": (1000.0, 0.3, False, {}),
    "100Hz_positions_noisy": (100.0, 0.5, False, {}),
    "100Hz_positions_delay": (100.0, 0.5, False, {"delay_s": 0.05}),
    "250Hz_velocities_delay": (250.0, 0.2, True, {"delay_s": 0.1}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_whole_streams_give_numpys_estimates(case) -> None:
    """The filter with its compiled step and without (numpy's way) over whole streams:
    the same warm flags and stamps, q, q̇, q̈ within 1e-12 of each quantity's range (the
    prediction rounds like BLAS's or one ulp off, and the filter carries it on; measured
    <= 2.1e-14 on 2026-12-06)."""
    rate, noise, vel, extra = CASES[case]
    settings = {k: v for k, v in extra.items() if k != "jitter"}
    stamps, z, zd = _stream(19, rate, noise, 3, extra.get("jitter", 0.0))
    fast, slow = make_estimator("kalman", N, settings), make_estimator("kalman", N, settings)
    assert fast._fast is not None
    slow._fast = None
    got = {k: [] for k in ("fast", "slow")}
    for i in range(len(stamps)):
        for name, est in (("fast", fast), ("slow", slow)):
            warm = est.update(int(stamps[i]), z[i], zd[i] if vel else None)
            est.learn()
            got[name].append((warm, est.stamp_ns, est.q.copy(), est.qd.copy(), est.qdd.copy()))
    assert [g[:2] for g in got["fast"]] == [g[:2] for g in got["slow"]]
    assert fast.discontinuities == slow.discontinuities >= 1 and fast.outliers == slow.outliers
    for j, what in ((2, "q"), (3, "qd"), (4, "qdd")):
        a = np.array([g[j] for g in got["fast"]])
        b = np.array([g[j] for g in got["slow"]])
        scale = np.ptp(b, axis=0).max()
        assert np.abs(a - b).max() <= 1e-12 * scale, (what, np.abs(a - b).max() / scale)


def test_input_the_kernel_cannot_take_runs_numpys_way() -> None:
    """float32 samples (a driver's) are refused by the compiled step: the filter runs numpy's
    way for them and gives the same estimates as float64 samples of the same values."""
    stamps, z, _zd = _stream(19, 1000.0, 0.3, 4)
    z32 = z.astype(np.float32)
    a, b = make_estimator("kalman", N), make_estimator("kalman", N)
    for i in range(600):
        a.update(int(stamps[i]), z32[i], None)
        b.update(int(stamps[i]), z32[i].astype(float), None)
        np.testing.assert_allclose(a.qdd, b.qdd, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(b.qdd).max()))


def test_copies_and_pickles_carry_their_own_step() -> None:
    stamps, z, _ = _stream(19, 1000.0, 0.3, 5)
    est = make_estimator("kalman", N)
    for i in range(300):
        est.update(int(stamps[i]), z[i], None)
    for other in (copy.deepcopy(est), pickle.loads(pickle.dumps(est))):  # noqa: S301 - ours
        assert other._fast is not None and other._fast is not est._fast
        keep = est.q.copy()
        for i in range(300, 320):
            other.update(int(stamps[i]), z[i], None)
        np.testing.assert_array_equal(est.q, keep)  # the original's arrays untouched
    twin = copy.deepcopy(est)
    for i in range(300, 400):
        est.update(int(stamps[i]), z[i], None)
        twin.update(int(stamps[i]), z[i], None)
        np.testing.assert_array_equal(est.qdd, twin.qdd)
