"""The noise estimator's compiled store (estimation/noise_step.py, _noise_step.c) against
Python's (noise_store.SampleRings._store), the reference it replaces: whole streams of every
kind the store must tell apart (uniform, jittered, stalls and bursts, a gap, a new rate,
30 Hz dropouts, restarts and shifts, velocities or not) give the same estimates to the bit,
through the estimator alone and through the Kalman filter; what it leaves to Python; what it
refuses."""

from __future__ import annotations

import copy
import math
import pickle
from array import array

import numpy as np
import pytest

from forearm_dynamics import get_movement
from forearm_dynamics.estimation import make_estimator, noise_step
from forearm_dynamics.estimation.noise import SPACING_S, NoiseEstimator
from forearm_dynamics.estimation.noise_store import (
    NEW_RATE,
    NOT_STORED,
    Ctr,
    Rate,
    fields,
)

pytestmark = pytest.mark.unit

N = 20
T0 = 1_700_000_000_000_000_000


def test_the_compiled_store_is_built() -> None:
    """setup.py builds it wherever a C compiler is (every machine this suite runs on)."""
    assert noise_step.available()
    assert NoiseEstimator(N)._fast is not None
    assert make_estimator("kalman", N).noise_estimator._fast is not None


def _stamps(kind: str, rate: float, n: int, rng) -> np.ndarray:
    step = 1.0 / rate
    t = np.arange(n) * step
    if kind == "jittered":  # a publisher's clock: +-20 % of a period
        t = np.sort(t + rng.uniform(-0.2, 0.2, n) * step)
    elif kind == "stalls":  # a loaded publisher: 3-20 ms stalls, then the owed samples in a burst
        out, k = [], 0.0
        while len(out) < n:
            out += [k + i * step for i in range(int(rng.integers(10, 21)))]
            stall = float(rng.uniform(3e-3, 20e-3))
            owed = max(1, round(stall / step))
            out += [out[-1] + stall + i * 0.2e-3 for i in range(owed)]
            k = out[-1] + step
        t = np.array(out[:n])
    elif kind == "gap":
        t[n // 2:] += 0.5
    elif kind == "new_rate":  # the rate doubles half way: a new stride and ring
        t[n // 2:] = t[n // 2 - 1] + np.arange(1, n - n // 2 + 1) * step / 2
    elif kind == "dropouts":  # a camera losing one frame in ten
        t = t[rng.random(n) > 0.1]
    return T0 + np.round(t * 1e9).astype(np.int64)


STREAMS = [(kind, rate) for kind in ("uniform", "jittered", "stalls", "gap", "new_rate")
           for rate in (1000.0, 100.0)] + [("dropouts", 30.0)]


def _run(est: NoiseEstimator, stamps, z, zd) -> dict:
    for k in range(len(stamps)):
        if k == len(stamps) // 3:
            est.restart()
        if k == len(stamps) // 4:
            est.shift(np.full(z.shape[1], 0.1))
        est.add(int(stamps[k]), z[k], None if zd is None else zd[k])
    return {"ms": est.ms, "ms_w": est.ms_w, "ms_v": est.ms_v, "ctr": list(est._ctr),
            "rate": list(est._rate), "counts": (est.evaluations, est.white_evaluations,
                                          est.velocity_evaluations, est.irregular_windows)}


@pytest.mark.parametrize("vel", [False, True], ids=["positions", "velocities"])
@pytest.mark.parametrize("kind,rate", STREAMS, ids=[f"{k}_{r:g}Hz" for k, r in STREAMS])
def test_whole_streams_give_pythons_estimates_to_the_bit(kind, rate, vel) -> None:
    """Every estimate, counter and period the same with the compiled store and without it;
    and the compiled store takes all but the first steps and each new rate."""
    rng = np.random.default_rng(7)
    stamps = _stamps(kind, rate, 3000 if rate > 100 or kind == "new_rate" else 800, rng)
    t = (stamps - T0) * 1e-9
    z = np.sin(np.outer(t, np.arange(1, N + 1) * 0.7)) + rng.normal(0.0, 1e-3, (len(t), N))
    zd = np.cos(np.outer(t, np.arange(1, N + 1))) + rng.normal(0.0, 1e-2, (len(t), N))
    fast = NoiseEstimator(N)
    left, in_python = [], []
    store, position = fast._store, fast._position_evaluation
    fast._store = lambda *a: left.append(a[0]) or store(*a)
    fast._position_evaluation = lambda: in_python.append(1) or position()
    a = _run(fast, stamps, z, zd if vel else None)
    b = _run(NoiseEstimator(N).python_store(), stamps, z, zd if vel else None)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert a["counts"][0] > 0 and a["counts"][1] > 0 and (a["counts"][2] > 0) == vel
    # the compiled store made the evaluations (Python's only on samples it left to _store)
    assert len(in_python) <= len(left), (len(in_python), a["counts"])

    # left to Python: the first two samples, the one after the restart, each new rate
    new_rates = len(left) - 3
    assert new_rates == 0 if kind != "new_rate" else 1 <= new_rates <= 3, left
    # the stride is set for a period within NEW_RATE of the stream's, at the doubled rate too
    # (a new rate re-strides; jitter and dropouts do not)
    step = np.diff(stamps[-400:]).mean() * 1e-9
    strided = a["rate"][Rate.STRIDE_DT]
    assert abs(strided - step) <= NEW_RATE * step, (strided, step)
    assert a["ctr"][Ctr.STRIDE] == max(1, round(SPACING_S / strided))


@pytest.mark.parametrize("rate", [1000.0, 100.0])
def test_clipped_evaluations_and_repeated_stamps_the_same(rate) -> None:
    """What the compiled evaluations do besides averaging, against Python's: a noise level
    that rises 30 x (evaluations winsorised, then a clip run that lets the new level in),
    repeated stamps (no difference across them), on uniform stamps (the plain differences)
    and jittered ones (divided differences on the real times); and samples lost in bursts
    (position windows whose blocks do not compare: skipped)."""
    rng = np.random.default_rng(11)
    n = 3000 if rate > 100 else 800
    base = T0 + np.round(np.arange(n) / rate * 1e9).astype(np.int64)
    base[n // 5::97] = base[n // 5 - 1::97][:len(base[n // 5::97])]  # a stamp repeated
    jit = np.maximum.accumulate(base + np.where(np.arange(n) > n // 2,
                                                rng.integers(-50_000, 50_000, n), 0))
    skipped = []
    keep = np.ones(n, bool)  # holes of 10-35 samples, a starved node's input
    for start in range(n // 10, n, max(n // 12, 40)):
        keep[start:start + int(rng.integers(10, 36))] = False
    for stamps in (base, jit, jit[keep]):
        n = len(stamps)
        t = (stamps - T0) * 1e-9
        level = np.where(np.arange(n) > 2 * n // 3, 30.0, 1.0)[:, None]
        z = np.sin(np.outer(t, np.arange(1, N + 1))) + level * rng.normal(0.0, 1e-3, (n, N))
        zd = np.cos(np.outer(t, np.arange(1, N + 1))) + level * rng.normal(0.0, 1e-2, (n, N))
        fast, slow = NoiseEstimator(N), NoiseEstimator(N).python_store()
        fast._position_evaluation = None  # the compiled store makes every evaluation
        clipped = 0
        for k in range(n):
            for est in (fast, slow):
                est.add(int(stamps[k]), z[k], zd[k])
            np.testing.assert_array_equal(fast.ms_v, slow.ms_v)
            np.testing.assert_array_equal(fast.ms_w, slow.ms_w)
            np.testing.assert_array_equal(fast._nclip_v, slow._nclip_v)
            clipped += int(fast._nclip_v.any())
        assert list(fast._ctr) == list(slow._ctr)
        np.testing.assert_array_equal(fast.ms, slow.ms)
        assert clipped > 0  # the winsorising ran, and clip runs were counted
        assert min(fast.velocity_evaluations, fast.white_evaluations, fast.evaluations) > 20
        skipped.append(fast.irregular_windows)
    assert skipped[-1] > 0 if rate > 100 else True  # blocks of 5 samples always compare


def test_through_the_kalman_filter_the_same_estimates() -> None:
    """The default estimator with its noise statistics stored either way: the same outputs
    (q, q̇, q̈ and the noise it believes) to the bit, at 1 kHz, noisy and jittered."""
    mv = get_movement(19)
    t = mv.sample_times(1000.0)
    q, _, _ = mv.evaluate(t)
    rng = np.random.default_rng(3)
    z = q + math.radians(0.3) * rng.standard_normal(q.shape)
    stamps = T0 + np.round(t * 1e9 + rng.uniform(-1e5, 1e5, len(t))).astype(np.int64)
    fast, slow = make_estimator("kalman", N), make_estimator("kalman", N)
    slow.noise_estimator.python_store()
    for k in range(len(stamps)):
        for est in (fast, slow):
            est.update(int(stamps[k]), z[k], None)
            est.learn()
        np.testing.assert_array_equal(fast.qdd, slow.qdd)
    np.testing.assert_array_equal(fast.q, slow.q)
    np.testing.assert_array_equal(fast.noise_per_joint(), slow.noise_per_joint())


def test_input_the_store_cannot_take_is_stored_in_python() -> None:
    """float32 samples and strided views are refused by the compiled store with nothing
    written; the estimator stores them in Python and estimates as from float64 copies."""
    rng = np.random.default_rng(4)
    stamps = _stamps("jittered", 1000.0, 1500, rng)
    z = rng.normal(0.0, 1e-3, (len(stamps), 2 * N))
    a, b = NoiseEstimator(N), NoiseEstimator(N)
    for k in range(len(stamps)):
        a.add(int(stamps[k]), z[k, ::2].astype(np.float32), z[k, 1::2])  # a strided view
        b.add(int(stamps[k]), z[k, ::2].astype(np.float32).astype(float), z[k, 1::2].copy())
    np.testing.assert_array_equal(a.ms, b.ms)
    np.testing.assert_array_equal(a.ms_v, b.ms_v)
    before = {k: np.array(v) for k, v in vars(a).items() if isinstance(v, (np.ndarray, array))}
    good = np.zeros(N)
    for bad in (np.zeros(N, np.float32), np.zeros(N + 1), np.zeros((2, N))[:, 0], [0.0] * N):
        with pytest.raises((ValueError, TypeError, BufferError)):
            a._fast.store(int(stamps[-1]) + 1_000_000, bad, None)
        with pytest.raises((ValueError, TypeError, BufferError)):
            a._fast.store(int(stamps[-1]) + 1_000_000, good, bad)
    with pytest.raises(TypeError):
        a._fast.store(1.5, good, None)
    for k, v in before.items():
        np.testing.assert_array_equal(getattr(a, k), v, err_msg=k)


def test_the_store_leaves_what_it_does_not_do_and_refuses_wrong_arrays() -> None:
    """No period yet, no stamp before (a restart), a new rate: NOT_STORED, nothing written.
    A Ctr whose fields are not the extension's is refused (they would read each other's
    counters); so are arrays of the wrong type or shape, and an unbound Store."""
    est = NoiseEstimator(N)
    q = np.zeros(N)
    assert est._fast.store(T0, q, None) == NOT_STORED  # no period yet
    est.add(T0, q, None)
    est.add(T0 + 1_000_000, q, None)
    assert est._fast.store(T0 + 2_000_000, q, None) == 0
    ctr = list(est._ctr)
    assert est._fast.store(T0 + 3_000_000 + 400_000_000, q, None) == 0  # a gap: its own
    assert est._ctr[Ctr.COUNT] == 1 and est._ctr[Ctr.LAST_NS] != ctr[Ctr.LAST_NS]
    est.restart()
    ctr = list(est._ctr)
    assert est._fast.store(T0 + 5_000_000_000, q, None) == NOT_STORED
    assert list(est._ctr) == ctr
    est.add(T0 + 5_000_000_000, q, None)
    t = T0 + 5_000_000_000
    for _ in range(400):  # steps of 0.5 ms: the mean moves a quarter off the stride's, a new rate
        t += 500_000
        ctr, rate = list(est._ctr), list(est._rate)
        if est._fast.store(t, q, None) == NOT_STORED:
            break
    else:
        raise AssertionError("a doubled rate was never left to Python")
    assert list(est._ctr) == ctr and list(est._rate) == rate
    arrays = (est._ctr, est._rate, est._raw, est._rawt, est._wring, est._wt, est._vring, est._vt,
              est.ms_w, est.ms_v, est._nclip_v, est.ms, est._nclip)
    params = (3.0, 0.04, 0.005, 0.02, 0.25, 2.5e-3, 8, 1000, 2.0, 4.0, 3, 5, 1.25, 3.0, 4)
    names = fields(Ctr) + fields(Rate)
    with pytest.raises(RuntimeError, match="rebuild"):
        noise_step.bind(*arrays, names[::-1], params)
    with pytest.raises(ValueError, match="ctr"):
        noise_step.Store(np.zeros(len(names)), *arrays[1:], params)
    with pytest.raises(ValueError, match="rawt"):
        noise_step.Store(*arrays[:3], np.zeros(3), *arrays[4:], params)
    with pytest.raises(ValueError, match="wring"):
        noise_step.Store(*arrays[:4], np.zeros((4, N + 1)), *arrays[5:], params)
    with pytest.raises(ValueError, match="ms_v"):
        noise_step.Store(*arrays[:9], np.zeros(N - 1), *arrays[10:], params)
    with pytest.raises(ValueError, match="nclip_v"):
        noise_step.Store(*arrays[:10], np.zeros(N), *arrays[11:], params)
    with pytest.raises(ValueError, match="DENSE_STRIDE"):
        noise_step.Store(*arrays, params[:6] + (0,) + params[7:])
    unbound = noise_step.Store.__new__(noise_step.Store)
    with pytest.raises(RuntimeError, match="not bound"):
        unbound.store(T0, q, None)


def test_copies_and_pickles_carry_their_own_store() -> None:
    rng = np.random.default_rng(5)
    stamps = _stamps("jittered", 1000.0, 800, rng)
    z = rng.normal(0.0, 1e-3, (len(stamps), N))
    est = NoiseEstimator(N)
    for k in range(400):
        est.add(int(stamps[k]), z[k], None)
    keep = est._raw.copy()
    for other in (copy.deepcopy(est), pickle.loads(pickle.dumps(est))):  # noqa: S301 - ours
        assert other._fast is not None and other._fast is not est._fast
        for k in range(400, 450):
            other.add(int(stamps[k]), z[k], None)
        np.testing.assert_array_equal(est._raw, keep)  # the original's ring untouched
    twin = copy.deepcopy(est)
    for k in range(400, 800):
        est.add(int(stamps[k]), z[k], None)
        twin.add(int(stamps[k]), z[k], None)
    np.testing.assert_array_equal(est.ms, twin.ms)
