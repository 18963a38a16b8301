"""Scoring an online estimate on a real recording against the offline practice (ROS-free).

A real recording has no truth. The reference is the practice of biomechanics: the recorded
positions low-passed at 6 Hz zero-phase, velocities and accelerations as derivatives of the
filtered signal (estimation/offline.zero_phase), inverse dynamics with the same model.
Whatever that band removes is error for an online torque, white or coloured, signal or
artefact. Used by benchmarks/real_corpus.py (issue 29) and anyone tuning an estimator on
the corpus's tuning half:

- `node_outputs`: the estimator's update() calls as torque_node makes them, each output
  stamped with the sample it estimates (`stamp_ns`: an earlier one with a delay), the
  warm-up outputs included (the node publishes them);
- `score`: per DOF, NRMSE = RMSE / peak-to-peak of the reference torque over the whole
  recording, after the settling time (`SETTLE_S`), and apart the first second (a start
  from rest, or mid-movement, is its own line, never hidden in the mean);
- `coverage`: the fraction of torque errors inside +-1.96 sigma and RMS(sigma) / RMSE;
- `rawness`: was a recording low-pass filtered by its authors (third differences and the
  top of its spectrum against its 6 Hz version)?
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..estimation import make_estimator
from ..estimation.offline import zero_phase
from ..filtering import lowpass

#: settling time (s) before the scored window: the estimators' warm-up and the start of a
#: recording (which may begin mid-movement) are scored apart, in the first second
SETTLE_S = 1.0
FIRST_S = 1.0


@dataclass
class Outputs:
    """What a torque node publishes for a stream: stamps and the state it estimates there."""

    stamps_ns: np.ndarray  # (M,) int64, a subset of the input's stamps
    q: np.ndarray  # (M, n)
    qd: np.ndarray
    qdd: np.ndarray
    warm: np.ndarray  # (M,) bool: False for the warm-up outputs (published all the same)


def node_outputs(stamps_ns: np.ndarray, q: np.ndarray, estimator: str,
                 settings: dict | None = None) -> Outputs:
    """The node's outputs for one uninterrupted stream (positions only): update() per
    sample; an output at `est.stamp_ns` whenever there is one (stream_node publishes the
    warm-up outputs too, counting them; a delay_s estimator outputs the sample delay_s
    back, nothing before; the last delay_s are never output, as in the node, which has no
    drain at the end of a stream)."""
    est = make_estimator(estimator, q.shape[1], settings or {})
    st, qs, qds, qdds, ws = [], [], [], [], []
    for k in range(len(stamps_ns)):
        warm = est.update(int(stamps_ns[k]), q[k], None)
        if est.stamp_ns is not None:
            st.append(est.stamp_ns)
            qs.append(est.q.copy())
            qds.append(est.qd.copy())
            qdds.append(est.qdd.copy())
            ws.append(bool(warm))
    return Outputs(np.asarray(st, np.int64), np.array(qs), np.array(qds), np.array(qdds),
                   np.asarray(ws, bool))


def practice(stamps_ns: np.ndarray, q: np.ndarray, cutoff_hz: float | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, qd, qdd) of the offline practice (6 Hz zero-phase + derivatives) at every stamp."""
    return zero_phase(np.asarray(stamps_ns, np.int64), q, cutoff_hz, max_gap_ns=10**18)


@dataclass
class Score:
    """Per DOF (columns asked for): NRMSE after settling, in the first second, and the
    normalising peak-to-peak (N·m)."""

    settled: np.ndarray
    first: np.ndarray
    ptp: np.ndarray
    settled_samples: int
    first_samples: int


def score(stamps_ns: np.ndarray, tau: np.ndarray, ref_stamps_ns: np.ndarray, tau_ref: np.ndarray,
          settle_s: float = SETTLE_S, first_s: float = FIRST_S) -> Score:
    """NRMSE of `tau` (at stamps_ns, a subset of ref_stamps_ns) against `tau_ref` (at every
    ref stamp): RMSE / peak-to-peak of tau_ref over the whole recording, per column.
    Windows count from the recording's first stamp: [t0 + settle_s, end] and [t0, t0 + first_s).
    A sample the estimate does not have (warm-up, a delay's tail) is not scored."""
    ref_stamps_ns = np.asarray(ref_stamps_ns, np.int64)
    idx = np.searchsorted(ref_stamps_ns, stamps_ns)
    if np.any(idx >= len(ref_stamps_ns)) or np.any(ref_stamps_ns[np.minimum(idx, len(ref_stamps_ns) - 1)]
                                                   != stamps_ns):
        raise ValueError("estimate stamps must be stamps of the reference")
    err = tau - tau_ref[idx]
    ptp = np.ptp(tau_ref, axis=0)
    rel = (np.asarray(stamps_ns, np.int64) - ref_stamps_ns[0]) * 1e-9
    late = rel >= settle_s
    early = rel < first_s

    def nr(mask):
        if not mask.any():
            return np.full(tau.shape[1], np.nan)
        return np.sqrt(np.mean(err[mask] ** 2, axis=0)) / np.where(ptp > 0, ptp, np.nan)
    return Score(nr(late), nr(early), ptp, int(late.sum()), int(early.sum()))


def coverage(err: np.ndarray, std: np.ndarray) -> dict[str, np.ndarray]:
    """Per column: fraction of |err| <= 1.96 std, and RMS(std) / RMSE (1: the σ's size is
    right on average). Rows with a non-finite std (warming up) are left out."""
    ok = np.isfinite(std).all(axis=1)
    e, s = err[ok], std[ok]
    inside = np.mean(np.abs(e) <= 1.96 * s, axis=0)
    rms_ratio = np.sqrt(np.mean(s**2, axis=0)) / np.sqrt(np.mean(e**2, axis=0))
    return {"inside_1p96": inside, "rms_std_over_rmse": rms_ratio, "samples": int(ok.sum())}


def rawness(x: np.ndarray, fs: float, cutoff_hz: float = 6.0) -> dict:
    """Was this signal (1-D, uniformly sampled at fs) low-pass filtered by its authors?

    d3_ratio: RMS of its third differences over that of its 6 Hz zero-phase version. A raw
    recording keeps its measurement noise, whose third differences dwarf the movement's
    (ratio >> 1); a signal already low-passed near the practice's band barely changes
    (ratio near 1). top_band_db: mean power in the top quarter of the spectrum below
    Nyquist over that between 2x and 3x the cutoff: a raw noise floor is about flat
    (0 dB; some -15 dB for coloured artefact), a 4th-order Butterworth at 10 Hz puts it
    30+ dB down at 100 Hz. raw: d3_ratio >= 3 and top_band_db >= -20."""
    from scipy.signal import welch

    x = np.asarray(x, float)
    d3 = np.diff(x, 3)
    d3f = np.diff(lowpass(x, fs, cutoff_hz), 3)
    ratio = float(np.sqrt(np.mean(d3**2)) / max(float(np.sqrt(np.mean(d3f**2))), 1e-300))
    f, p = welch(x - x.mean(), fs=fs, nperseg=min(len(x), 256))
    top = p[(f >= 0.75 * fs / 2) & (f < fs / 2)].mean()
    mid = p[(f >= 2 * cutoff_hz) & (f < 3 * cutoff_hz)].mean()
    db = float(10 * math.log10(max(float(top), 1e-300) / max(float(mid), 1e-300)))
    return {"d3_ratio": ratio, "top_band_db": db, "raw": bool(ratio >= 3.0 and db >= -20.0)}
