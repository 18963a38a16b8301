"""Issue 29's practice gain (opt-in: estimator.practice_band_hz 6, kalman_min_bandwidth_hz 0):
the causal estimator against the offline practice (6 Hz zero-phase + derivatives) on the
sensor content that real recordings have and the library's movements lack.

- A joint with little white noise but coloured content above 6 Hz (soft-tissue artefact,
  IK jitter) is smoothed to the practice's band: its q̈ follows the practice's, not the
  content the practice removes.
- A slow movement does not get the library's bandwidth: its jerk level is measured, and the
  filter is as narrow as that movement needs.
- The kernels that give the practice's derivatives online are exact on cubics.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import butter, sosfilt

from forearm_dynamics.estimation import make_estimator
from forearm_dynamics.estimation.offline import zero_phase
from forearm_dynamics.estimation.practice_gain import practice_kernels

pytestmark = pytest.mark.unit

RATE = 100.0
#: the practice gain is opt-in (kalman.py): the measured setting, and the same filter without it
GAIN = {"practice_band_hz": 6.0, "kalman_min_bandwidth_hz": 0.0}
PLAIN = {"practice_band_hz": 0.0, "kalman_min_bandwidth_hz": 0.0}
SETTLE_S = 3.0


def stream(q: np.ndarray, name: str, settings: dict) -> tuple[np.ndarray, np.ndarray]:
    """(qdd (N, n) of every sample, the estimator) from a positions-only stream at RATE."""
    t = np.round(np.arange(len(q)) * 1e9 / RATE).astype(np.int64) + 10**9
    est = make_estimator(name, q.shape[1], settings)
    out = np.zeros_like(q)
    for k in range(len(q)):
        est.update(int(t[k]), q[k], None)
        out[k] = est.qdd
    return out, est


def practice_qdd(q: np.ndarray) -> np.ndarray:
    t = np.round(np.arange(len(q)) * 1e9 / RATE).astype(np.int64)
    return zero_phase(t, q, 6.0)[2]


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def high_band(x: np.ndarray) -> float:
    """RMS of x above 7 Hz (zero-phase high-pass)."""
    from scipy.signal import sosfiltfilt
    return rms(sosfiltfilt(butter(4, 7.0, "highpass", fs=RATE, output="sos"), x))


def test_coloured_content_above_the_band_is_smoothed_like_the_practice() -> None:
    """A reach-like 0.4 Hz movement with 0.005 deg white noise (a marker elbow: the white level
    reads near the floor) and 0.3 deg of coloured content at 7-14 Hz (artefact)."""
    rng = np.random.default_rng(3)
    n = 1500
    t = np.arange(n) / RATE
    move = 0.6 * np.sin(2 * np.pi * 0.4 * t) + 0.2 * np.sin(2 * np.pi * 0.9 * t + 1.0)
    coloured = sosfilt(butter(4, (7.0, 14.0), "bandpass", fs=RATE, output="sos"), rng.standard_normal(n))
    coloured *= math.radians(0.3) / rms(coloured)
    q = (move + coloured + math.radians(0.005) * rng.standard_normal(n))[:, None]
    ref = practice_qdd(q)[:, 0]
    late = slice(int(SETTLE_S * RATE), None)
    kal, _ = stream(q, "kalman", GAIN)
    plain, _ = stream(q, "kalman", PLAIN)
    bw, _ = stream(q, "butterworth", {"butterworth_cutoff_hz": 6.0})
    e_k = rms(kal[late, 0] - ref[late])
    e_plain = rms(plain[late, 0] - ref[late])
    e_bw = rms(bw[late, 0] - ref[late])
    # what the practice removes does not pass: the q̈ above 7 Hz is a fraction of the plain
    # filter's (which believes the small white level and follows the artefact)
    assert high_band(kal[late, 0]) <= 0.3 * high_band(plain[late, 0])
    # ... and against the practice it beats the causal 6 Hz Butterworth
    assert e_k <= 0.85 * e_bw, (e_k, e_bw, e_plain)
    assert e_k <= 0.7 * e_plain, (e_k, e_plain)
    # ... and the default (practice gain off, 7 Hz cap: this content is believed coloured and
    # kept) is what it improves on; measured q̈ RMSE 2.69 with the gain, 4.77 the filter
    # alone with the cap off, 6.12 the default, 6.90 the Butterworth (rad/s²)
    default, _ = stream(q, "kalman", {})
    assert e_k <= 0.5 * rms(default[late, 0] - ref[late]), (e_k, rms(default[late, 0] - ref[late]))


def test_a_slow_movement_does_not_get_the_library_bandwidth() -> None:
    """A slow 0.15 Hz movement with 0.2 deg white noise: its measured jerk density is far
    below the library's (kalman_jerk_psd 3e3, tuned on 0.5 s movements), so the filter runs
    narrower, and its q̈ is closer to the practice's than at the library's bandwidth."""
    rng = np.random.default_rng(5)
    n = 2000
    t = np.arange(n) / RATE
    q = (0.8 * np.sin(2 * np.pi * 0.15 * t) + math.radians(0.2) * rng.standard_normal(n))[:, None]
    ref = practice_qdd(q)[:, 0]
    late = slice(int(SETTLE_S * RATE), None)
    kal, est = stream(q, "kalman", GAIN)
    lib, est_lib = stream(q, "kalman", PLAIN)
    psd = est.values["kalman_jerk_psd"]
    dt = 1.0 / RATE

    def bandwidth_hz(r: float) -> float:  # the filter's bandwidth at its noise belief
        return (psd / (r * r * dt)) ** (1 / 6) / (2 * math.pi)

    b_slow = bandwidth_hz(float(est.gain_noise_per_joint()[0]))
    b_lib = bandwidth_hz(float(est_lib.gain_noise_per_joint()[0]))
    assert est._pgain.jerk_psd()[0] < 0.01 * psd  # measured: the movement's own jerk level
    assert b_slow < 0.7 * b_lib, (b_slow, b_lib)
    assert rms(kal[late, 0] - ref[late]) <= 0.5 * rms(lib[late, 0] - ref[late])


@pytest.mark.parametrize("rate", [60.0, 100.0, 1000.0])
def test_practice_kernels_are_exact_on_cubics_and_follow_the_band(rate: float) -> None:
    k = practice_kernels(1.0 / rate, 6.0, 0.2)
    h = (k.shape[1] - 1) // 2
    t = np.arange(-h, h + 1) / rate
    for p, want in enumerate(np.diag([1.0, 1.0, 2.0, 6.0])):
        got = [float(k[i] @ t**p) for i in range(4)]
        np.testing.assert_allclose(got, want, atol=1e-6)
    # q̈ at 2 Hz within 15 % of the zero-phase filter's, 10 Hz suppressed like it
    for f, lo, hi in ((2.0, 0.85, 1.15), (10.0, 0.0, 0.05)):
        g = abs(k[2] @ np.exp(2j * np.pi * f * t)) / (2 * np.pi * f) ** 2
        assert lo <= g <= hi, (f, g)
