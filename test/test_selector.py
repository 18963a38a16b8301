"""The opt-in `selector` estimator (estimation/selector.py, issue 29): per joint, the default
Kalman filter or the blend 0.75 practice-gain Kalman + 0.25 causal 6 Hz Butterworth, chosen
online against the offline practice on the past.

- Exact input and given velocities stay on the default Kalman filter (its output, to
  rounding): the practice is not the truth there.
- A raw-recording-like joint (little white noise, coloured content above 6 Hz) moves to the
  blend, and its q̈ is closer to the practice's than the default's and the Butterworth's.
- The output never jumps at a change: the weight moves by at most one cross-fade step.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import butter, sosfilt

from forearm_dynamics.estimation import make_estimator
from forearm_dynamics.estimation.offline import zero_phase
from forearm_dynamics.estimation.selector import FADE_S

pytestmark = pytest.mark.unit

RATE = 100.0
SETTLE_S = 3.0


def run(q: np.ndarray, name: str, qd: np.ndarray | None = None, rate: float = RATE):
    """(q, qd, qdd) (3, N, n) of every sample, the weights of the selector (N, n), the estimator."""
    t = np.round(np.arange(len(q)) * 1e9 / rate).astype(np.int64) + 10**9
    est = make_estimator(name, q.shape[1])
    out = np.zeros((3, *q.shape))
    weights = np.zeros(q.shape)
    for k in range(len(q)):
        est.update(int(t[k]), q[k], None if qd is None else qd[k])
        out[:, k] = est.q, est.qd, est.qdd
        if name == "selector":
            weights[k] = est.weight
    return out, weights, est


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def reach(n: int, rate: float = RATE) -> np.ndarray:
    t = np.arange(n) / rate
    return 0.6 * np.sin(2 * np.pi * 0.4 * t) + 0.2 * np.sin(2 * np.pi * 0.9 * t + 1.0)


@pytest.mark.parametrize("rate", [100.0, 1000.0])
def test_exact_input_stays_on_the_default_kalman(rate: float) -> None:
    n = round(4 * rate)
    q = np.stack([reach(n, rate), 0.3 * reach(n, rate) ** 2, np.zeros(n)], axis=1)
    sel, w, _ = run(q, "selector", rate=rate)
    kal, _, _ = run(q, "kalman", rate=rate)
    assert (w == 1.0).all()
    np.testing.assert_allclose(sel, kal, rtol=0, atol=1e-9 * max(1.0, np.abs(kal).max()))


def test_given_velocities_stay_on_the_default_kalman() -> None:
    rng = np.random.default_rng(5)
    n = 600
    q = reach(n)[:, None] + math.radians(0.3) * rng.standard_normal((n, 1))
    qd = np.gradient(reach(n), 1 / RATE)[:, None] + math.radians(2.0) * rng.standard_normal((n, 1))
    sel, _, _ = run(q, "selector", qd)
    kal, _, _ = run(q, "kalman", qd)
    np.testing.assert_array_equal(sel, kal)


def test_a_raw_recording_like_joint_takes_the_blend_and_beats_both() -> None:
    """0.005 deg white noise (a marker elbow) and 0.3 deg of coloured content at 7-14 Hz."""
    rng = np.random.default_rng(3)
    n = 1500
    coloured = sosfilt(butter(4, (7.0, 14.0), "bandpass", fs=RATE, output="sos"), rng.standard_normal(n))
    coloured *= math.radians(0.3) / rms(coloured)
    q = (reach(n) + coloured + math.radians(0.005) * rng.standard_normal(n))[:, None]
    t = np.round(np.arange(n) * 1e9 / RATE).astype(np.int64)
    ref = zero_phase(t, q, 6.0)[2][:, 0]
    late = slice(int(SETTLE_S * RATE), None)
    sel, w, _ = run(q, "selector")
    errs = {name: rms(x[2, late, 0] - ref[late]) for name, x in
            (("selector", sel), ("kalman", run(q, "kalman")[0]), ("butterworth", run(q, "butterworth")[0]))}
    assert (w[late, 0] == 0.0).all(), "the noisy joint left the blend"
    assert errs["selector"] <= 0.6 * errs["kalman"], errs
    assert errs["selector"] <= 0.8 * errs["butterworth"], errs


def test_the_output_never_jumps_at_a_change() -> None:
    """A still joint with white noise, then a fast movement: whichever the selection does, the
    weight moves by at most one cross-fade step per sample."""
    rng = np.random.default_rng(11)
    n = 1200
    t = np.arange(n) / RATE
    move = np.where(t > 4.0, 0.8 * np.sin(2 * np.pi * 2.0 * (t - 4.0)), 0.0)
    q = np.stack([move + math.radians(0.5) * rng.standard_normal(n),
                  math.radians(1.0) * rng.standard_normal(n)], axis=1)
    _, w, est = run(q, "selector")
    step = (1.0 / RATE) / FADE_S
    assert np.abs(np.diff(w, axis=0)).max() <= step + 1e-12
    assert w.min() < 1.0  # the noisy joints left the default at some point
    est.reset()
    assert (est.weight == 1.0).all()
