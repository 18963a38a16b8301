"""The noise groups' compiled covariance step (kalman_step.Gains, _kalman_step.c) against
Python's loop (noise_groups.NoiseGroups._python_covariance_step), the reference it replaces
for groups seated at their steady state: whole streams of every kind the step must tell
apart (regular, jittered within and beyond JITTER, a gap, a new rate, restarts, noise that
changes level and regroups, velocities or not, a delay) give the same estimates, covariances
and gains to the bit; what it leaves to Python; what it refuses."""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest

from forearm_dynamics.estimation import kalman_step, make_estimator
from forearm_dynamics.estimation import noise_groups as ng
from forearm_dynamics.estimation.noise_groups import JITTER, Col

pytestmark = pytest.mark.unit

N = 20
T0 = 1_700_000_000_000_000_000


def test_the_compiled_gains_are_built() -> None:
    """setup.py builds them wherever a C compiler is (every machine this suite runs on)."""
    assert kalman_step.Gains is not None
    est = make_estimator("kalman", N)
    est.update(T0, np.zeros(N), None)
    est.update(T0 + 10**6, np.zeros(N), None)
    assert est._gfast is not None


def _stream(kind: str, rate: float, seconds: float = 4.0):
    """(stamps ns, q, qd): a smooth movement on N joints, with noise whose level changes
    every second (the groups regroup), stamps as `kind` says."""
    rng = np.random.default_rng(11)
    dt = 1.0 / rate
    k = round(seconds * rate)
    t = np.arange(k) * dt
    w = 2.0 * math.pi * np.linspace(0.3, 1.5, N)  # a smooth movement per joint
    q, qd = 0.5 * np.sin(t[:, None] * w), 0.5 * w * np.cos(t[:, None] * w)
    level = np.radians(np.where((t.astype(int) % 2) == 0, 0.05, 0.6))
    q = q + level[:, None] * rng.standard_normal(q.shape)
    steps = np.full(k, dt)
    if kind == "jitter":  # within JITTER and beyond it, like a publisher's wall clock
        steps *= 1.0 + rng.uniform(-0.15, 0.15, k)  # (±25 %: a restart never settles)
    elif kind == "gap":  # 0.3 s missing: the filter predicts across it
        steps[k // 2] += 0.3
    elif kind == "new_rate":  # the sensor halves its rate half-way
        steps[k // 2:] *= 2.0
    stamps = T0 + np.cumsum(np.rint(steps * 1e9).astype(np.int64))
    return stamps, q, qd


def _run(est, stamps, q, qd, vel: bool, restart_at: int | None):
    out = []
    for i in range(len(stamps)):
        if i == restart_at:
            est.reset()
        est.update(int(stamps[i]), q[i], qd[i] if vel else None)
        est.learn()
        row = [est.q, est.qd, est.qdd, est._Kp.ravel(), est._Kv.ravel(), est._sig,
               est.covariance().ravel()]
        out.append(np.concatenate(row))
    gains = [np.concatenate([g.gain.ravel(), g.prior.ravel(), [g.dt]]) for g in est.noise_groups()]
    return np.array(out), gains, est._gstate.copy()


@pytest.mark.parametrize("vel", [False, True])
@pytest.mark.parametrize("kind,rate,delay", [
    ("regular", 1000.0, 0.0), ("jitter", 1000.0, 0.0), ("jitter", 100.0, 0.0),
    ("gap", 1000.0, 0.0), ("new_rate", 1000.0, 0.0), ("jitter", 1000.0, 0.05),
])
def test_whole_streams_give_pythons_estimates_to_the_bit(kind, rate, delay, vel, monkeypatch) -> None:
    # long enough for the groups to be seated again after a restart (100 Hz) or a new rate
    stamps, q, qd = _stream(kind, rate, 10.0 if rate < 500.0 or kind == "new_rate" else 4.0)
    calls = {"done": 0, "python": 0, "last_python": 0}
    bind = kalman_step.bind_gains

    class Counted:  # the compiled step, counting what it did and what it left to Python
        def __init__(self, fast):
            self.fast = fast

        def step(self, *args):
            r = self.fast.step(*args)
            calls["done" if r >= 0 else "python"] += 1
            if r < 0:
                calls["last_python"] = calls["done"] + calls["python"]
            return r

    monkeypatch.setattr(ng.kalman_step, "bind_gains", lambda *a: Counted(bind(*a)))
    settings = {"delay_s": delay}
    compiled = _run(make_estimator("kalman", N, settings), stamps, q, qd, vel, len(stamps) // 3)
    monkeypatch.setattr(ng.kalman_step, "bind_gains", bind)
    python = _run(make_estimator("kalman", N, settings).python_gains(), stamps, q, qd, vel,
                  len(stamps) // 3)
    assert np.array_equal(compiled[0], python[0])
    assert len(compiled[1]) == len(python[1]) > 0
    assert all(np.array_equal(a, b) for a, b in zip(compiled[1], python[1]))
    assert np.array_equal(compiled[2], python[2])
    # Python's loop only at the start, a restart and a new rate, until the groups are seated
    # again (at ±15 % jitter with velocities ~0.75 s: the rule's SETTLED); the compiled step
    # after that, to the end
    assert calls["python"] > 0 and calls["done"] > 0.4 * len(stamps), calls
    assert calls["last_python"] < 0.8 * len(stamps), calls


def _seated_filter(vel: bool):
    """A filter past its start at 1 kHz, every group seated and still."""
    est = make_estimator("kalman", N, {"kalman_noise_deg": 0.3})
    qd = np.zeros(N) if vel else None
    for i in range(400):
        est.update(T0 + i * 10**6, np.zeros(N), qd)
        est.learn()
    assert (est._gstate[:, Col.SEATED] > 0).all() and (est._gstate[:, Col.STILL] == 1).all()
    return est


def _arrays(est):
    return [a.copy() for a in (est._gstate, est._Kp, est._Kv, est._sig)]


@pytest.mark.parametrize("vel", [False, True])
def test_a_seated_group_off_its_period_gets_pythons_gain(vel) -> None:
    """One step 2 x the period (a dropped sample): the gain at that dt, the steady state kept,
    the group not still; the step after, back at the period, still again: as Python's loop."""
    a, b = _seated_filter(vel), _seated_filter(vel).python_gains()
    for dt in (2e-3, 1e-3, 1e-3, 1.05e-3, 0.5e-3, 0.5e-3):
        p = a._gstate[:, Col.P:Col.P + 6].copy()
        assert a._gfast.step(dt, 1e-3, a.psd, vel, JITTER) in (0, 1)
        b._python_covariance_step(dt, vel, 1e-3)
        assert all(np.array_equal(x, y) for x, y in zip(_arrays(a), _arrays(b)))
        assert np.array_equal(a._gstate[:, Col.P:Col.P + 6], p)  # the steady state stays
        assert (a._gstate[:, Col.STILL] == (abs(dt - 1e-3) <= JITTER * 1e-3)).all()
    assert (a._gstate[:, Col.STILL] == 0).all()  # 0.5 ms is beyond JITTER
    assert a._gfast.step(1e-3, 1e-3, a.psd, vel, JITTER) == 1  # back within: computed once,
    assert a._gfast.step(1e-3, 1e-3, a.psd, vel, JITTER) == 0  # then kept,
    assert a._gfast.step(0.95e-3, 1e-3, a.psd, vel, JITTER) == 0  # within JITTER too


def test_what_it_leaves_to_python_it_does_not_touch() -> None:
    """A group not seated (settling after a restart, or seated at another period): -1 and
    every array as it was."""
    est = _seated_filter(False)
    before = _arrays(est)
    assert est._gfast.step(1.5e-3, 1.5e-3, est.psd, False, JITTER) == -1  # a new period
    assert all(np.array_equal(x, y) for x, y in zip(before, _arrays(est)))
    est._gstate[0, Col.SEATED] = 0.0  # settling
    before = _arrays(est)
    assert est._gfast.step(2e-3, 1e-3, est.psd, False, JITTER) == -1
    assert all(np.array_equal(x, y) for x, y in zip(before, _arrays(est)))


def test_wrong_arrays_and_layouts_are_refused() -> None:
    est = _seated_filter(True)
    args = {"state": est._gstate, "gidx": est._gidx, "r_gate": est._r_gate, "kp": est._Kp,
            "kv": est._Kv, "sig": est._sig}
    good = kalman_step.Gains(**args)
    assert good.step(2e-3, 1e-3, est.psd, True, JITTER) == 1
    for name, bad in [("state", est._gstate[:, :20].copy()), ("state", est._gstate.astype(np.float32)),
                      ("gidx", est._gidx.astype(np.int32)), ("r_gate", np.zeros(N + 1)),
                      ("kp", np.zeros((2, N))), ("kv", np.asfortranarray(np.zeros((3, N)))),
                      ("sig", np.zeros(N, np.float32))]:
        with pytest.raises(ValueError, match=name):
            kalman_step.Gains(**{**args, name: bad})
    read_only = est._gstate.copy()
    read_only.flags.writeable = False
    with pytest.raises(ValueError, match="state: a writable"):
        kalman_step.Gains(**{**args, "state": read_only})
    with pytest.raises(RuntimeError, match="not bound"):
        kalman_step.Gains.__new__(kalman_step.Gains).step(1e-3, 1e-3, 1.0, True, JITTER)
    with pytest.raises(TypeError):
        good.step(1e-3, 1e-3, est.psd, True)
    with pytest.raises(RuntimeError, match="rebuild"):
        kalman_step.bind_gains(est._gstate, {**Col.layout(), "DT": Col.DT + 1}, est._gidx,
                               est._r_gate, est._Kp, est._Kv, est._sig)
    est._gidx[3] = len(est._gstate)  # not a group: refused before anything is written
    before = _arrays(est)
    with pytest.raises(ValueError, match="gidx"):
        good.step(3e-3, 1e-3, est.psd, True, JITTER)
    assert all(np.array_equal(x, y) for x, y in zip(before, _arrays(est)))


def test_copies_and_pickles_carry_their_own_step() -> None:
    est = _seated_filter(False)
    state = est._gstate.copy()
    for other in (copy.deepcopy(est), pickle.loads(pickle.dumps(est))):  # noqa: S301 - our own
        assert other._gfast is not None and other._gfast is not est._gfast
        other.update(T0 + 400 * 10**6 + 2 * 10**6, np.full(N, math.radians(1.0)), None)
        assert not np.array_equal(other._gstate, state)  # its own groups stepped ...
        assert np.array_equal(est._gstate, state)  # ... not the original's
