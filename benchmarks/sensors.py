"""The sensor zoo of the estimation benchmark: realistic sensor models and real recordings.

Each model says where its numbers come from. A sensor that measures only some joints
streams the others held (constant, as torque_node's `missing_joints: hold` does): its
truth is the movement with those joints held at their start posture.

- mocap_ik: motion capture through inverse kinematics, the arm only (elbow, pro/sup, wrist;
  thumb and fingers held), 100 and 250 Hz. Per-joint noise 0.1 deg (elbow) to 1 deg
  (pro/sup), low-pass coloured (first-order, correlation time 20-50 ms: IK and soft-tissue
  artefact), rare single-sample spikes of 5-20 deg (a marker swap, 0.1 % of samples per
  joint). Ranges: issue 16 (from an OpenSim IK result whose pro/sup was 10 x noisier than
  its elbow by third differences, 0.74 vs 0.076 deg); the recordings below agree in kind
  (their third-difference levels are printed by this benchmark).
- glove: a data glove, fingers and thumb only (arm held), 90 Hz, 1.5 deg white noise,
  quantised to 0.5 deg (issue 16: 1-2 deg, 60-120 Hz, quantised).
- camera: marker-less hand tracking, all joints, 30 Hz, 3 deg white noise, gaps of
  50-300 ms every 2 s on average (issue 16: 2-5 deg, 30 Hz, gaps).
- encoder: joint encoders, all joints, 1 kHz, 12-bit positions (4096 counts per turn:
  0.088 deg steps) and velocities with 2 deg/s white noise (a differentiated or
  tachometer velocity; issue 16, the estimation benchmark's velocity row).
- held_exact: issue 16's reproduction: 100 Hz, 0.5 deg white noise on the joints that
  move, exact values on those that do not.

Real recordings (`recordings()`): OpenSim IK results, positions only, at their own rate;
elbow, pro/sup and wrist mapped to the model's joints (other joints held at 0); scored
against the offline practice (6 Hz zero-phase + derivatives) of the same data, since
there is no truth. benchmarks/data/README.md says where each comes from and its licence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import make_interp_spline
from scipy.signal import butter, filtfilt

from forearm_dynamics.description import DOF_GROUPS, JOINT_NAMES
from forearm_dynamics.estimation.base import SettingSpec, StateEstimator

HERE = Path(__file__).resolve().parent
ARM = ("elbow_flexion", "pro_sup", "wrist_flexion", "wrist_deviation")
HAND = tuple(j for j in JOINT_NAMES if j not in ARM)


@dataclass(frozen=True)
class Sensor:
    name: str
    rate_hz: float
    measured: tuple[str, ...]
    noise_deg: dict[str, float]  # per measured joint (others: default)
    default_noise_deg: float = 0.0
    tau_s: dict[str, float] = field(default_factory=dict)  # coloured: correlation time
    spike_prob: float = 0.0
    quantum_deg: float = 0.0
    gap_every_s: float = 0.0
    velocity_noise_dps: float | None = None
    moving_only: bool = False  # held_exact: the noise only on the movement's moving joints
    fresh: bool = False  # a fresh estimator per movement (held_exact: one recording each)
    source: str = ""

    def noise(self, joint: str) -> float:
        return math.radians(self.noise_deg.get(joint, self.default_noise_deg))


def zoo() -> list[Sensor]:
    mocap = {"measured": ARM, "noise_deg": {"elbow_flexion": 0.1, "pro_sup": 1.0,
                                            "wrist_flexion": 0.3, "wrist_deviation": 0.5},
             "tau_s": {"elbow_flexion": 0.02, "pro_sup": 0.05, "wrist_flexion": 0.03,
                       "wrist_deviation": 0.03},
             "spike_prob": 1e-3, "source": "issue 16 ranges; OpenSim IK results (benchmarks/data)"}
    return [
        Sensor("mocap_ik_100hz", 100.0, **mocap),
        Sensor("mocap_ik_250hz", 250.0, **mocap),
        Sensor("glove_90hz", 90.0, HAND, {}, 1.5, quantum_deg=0.5, source="issue 16 ranges"),
        Sensor("camera_30hz", 30.0, JOINT_NAMES, {}, 3.0, gap_every_s=2.0, source="issue 16 ranges"),
        Sensor("encoder_1khz", 1000.0, JOINT_NAMES, {}, 0.0, quantum_deg=360.0 / 4096,
               velocity_noise_dps=2.0, source="12-bit encoder; velocity noise as the 1 kHz row"),
        Sensor("held_exact_100hz", 100.0, JOINT_NAMES, {}, 0.5, moving_only=True, fresh=True,
               source="issue 16 reproduction"),
    ]


def ou(rng, n: int, sigma: float, tau: float, rate: float) -> np.ndarray:
    """First-order low-pass (Ornstein-Uhlenbeck) noise, std sigma, correlation time tau."""
    a = math.exp(-1.0 / (tau * rate))
    w = rng.normal(0.0, sigma * math.sqrt(1 - a * a), n)
    x = np.empty(n)
    x[0] = rng.normal(0.0, sigma)
    for k in range(1, n):
        x[k] = a * x[k - 1] + w[k]
    return x


def held_movement(mv, measured: tuple[str, ...]):
    """evaluate(t) of the movement with the unmeasured joints held at their start posture."""
    keep = np.array([j in measured for j in JOINT_NAMES])

    def evaluate(t):
        q, qd, qdd = mv.evaluate(t)
        q0, _, _ = mv.evaluate(np.array([0.0]))
        q = np.where(keep, q, q0[0])
        return q, np.where(keep, qd, 0.0), np.where(keep, qdd, 0.0)
    return evaluate


def stream(sensor: Sensor, mv, q: np.ndarray, qd: np.ndarray, rng
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(keep mask of delivered samples, positions, velocities or None) of this sensor."""
    n = q.shape[0]
    z = q.copy()
    moving = set(mv.moving)
    for j, name in enumerate(JOINT_NAMES):
        if name not in sensor.measured or (sensor.moving_only and name not in moving):
            continue
        r = sensor.noise(name)
        if not r:
            continue
        tau = sensor.tau_s.get(name, 0.0)
        z[:, j] += ou(rng, n, r, tau, sensor.rate_hz) if tau else rng.normal(0.0, r, n)
    if sensor.spike_prob:
        cols = [JOINT_NAMES.index(j) for j in sensor.measured]
        hit = rng.random((n, len(cols))) < sensor.spike_prob
        size = np.radians(rng.uniform(5.0, 20.0, hit.shape)) * rng.choice([-1.0, 1.0], hit.shape)
        z[:, cols] += np.where(hit, size, 0.0)
    if sensor.quantum_deg:
        step = math.radians(sensor.quantum_deg)
        z = np.round(z / step) * step
    zv = None
    if sensor.velocity_noise_dps is not None:
        zv = qd + rng.normal(0.0, math.radians(sensor.velocity_noise_dps), qd.shape)
    keep = np.ones(n, bool)
    if sensor.gap_every_s:
        k = 0
        while True:
            k += int(rng.exponential(sensor.gap_every_s) * sensor.rate_hz) + 1
            if k >= n:
                break
            length = int(rng.uniform(0.05, 0.3) * sensor.rate_hz)
            keep[k:k + length] = False
            k += length
    return keep, z, zv


class OpenSimRTStyle(StateEstimator):
    """OpenSimRT's low-pass smooth filter as its description reads (Stanev et al.,
    OpenSimRT; written from the description, not its code): a buffer of the last 35
    samples, low-passed zero-phase (2nd-order Butterworth at 6 Hz, forward-backward over
    the buffer), a cubic spline through the filtered buffer on the real times, value and
    derivatives read 14 samples back from the newest: a fixed delay of 14 samples."""

    name = "opensimrt_style"
    settings = (SettingSpec("memory", 35, "samples", "buffer length", 5, 1000),
                SettingSpec("delay", 14, "samples", "samples back the output is read", 1, 500),
                SettingSpec("cutoff_hz", 6.0, "Hz", "low-pass cutoff", 0.1, 100.0))

    def __init__(self, n: int, settings):
        super().__init__(n, settings)
        self.memory = int(self.values["memory"])
        self.lagk = int(self.values["delay"])
        self.delay_s = 1.0  # > 0: run() aligns the outputs by stamp_ns
        self.reset()

    def reset(self) -> None:
        self._t_ns = None
        self._buf_t: list[int] = []
        self._buf_q: list[np.ndarray] = []

    def update(self, t_ns, q, qd) -> bool:
        self.check(t_ns, q, qd)
        self._t_ns = t_ns
        self._buf_t.append(t_ns)
        self._buf_q.append(q.copy())
        if len(self._buf_t) > self.memory:
            self._buf_t.pop(0)
            self._buf_q.pop(0)
        if len(self._buf_t) < self.memory:
            self.stamp_ns = None
            return False
        t = (np.array(self._buf_t) - self._buf_t[0]) * 1e-9
        x = np.array(self._buf_q)
        fs = (len(t) - 1) / t[-1]
        b, a = butter(2, min(self.values["cutoff_hz"] / (fs / 2), 0.9))
        f = filtfilt(b, a, x, axis=0)
        sp = make_interp_spline(t, f, k=3, axis=0)
        i = self.memory - 1 - self.lagk
        self.q[:], self.qd[:], self.qdd[:] = sp(t[i]), sp(t[i], 1), sp(t[i], 2)
        self.stamp_ns = self._buf_t[i]
        return True

    def lag(self, dt, velocity_given):  # noqa: ARG002 - centred window: no lag at its stamp
        return {"q": 0.0, "qd": 0.0, "qdd": 0.0}


# -- real recordings ---------------------------------------------------------------------
#: OpenSim coordinate -> model joint (right arm of the Rajagopal / Hamner full-body models,
#: arm26's elbow); the other joints are held at 0
NAME_MAP = {"elbow_flex_r": "elbow_flexion", "pro_sup_r": "pro_sup", "wrist_flex_r": "wrist_flexion",
            "wrist_dev_r": "wrist_deviation", "r_elbow_flex": "elbow_flexion"}


@dataclass(frozen=True)
class Recording:
    name: str
    stamps_ns: np.ndarray
    q: np.ndarray  # (N, 20) rad
    measured: tuple[str, ...]
    moving: tuple[str, ...]
    source: str


def read_mot(path: Path) -> tuple[list[str], np.ndarray, bool]:
    lines = path.read_text(encoding="utf-8").splitlines()
    end = next(i for i, line in enumerate(lines) if line.strip().lower() == "endheader")
    degrees = any(line.strip().lower() == "indegrees=yes" for line in lines[:end])
    cols = lines[end + 1].split()
    data = np.array([[float(x) for x in line.split()] for line in lines[end + 2:] if line.strip()])
    return cols, data, degrees


def recording(path: Path, source: str) -> Recording:
    cols, data, degrees = read_mot(path)
    t = data[:, 0]
    q = np.zeros((len(t), len(JOINT_NAMES)))
    measured = []
    for c, name in NAME_MAP.items():
        if c in cols:
            x = data[:, cols.index(c)]
            q[:, JOINT_NAMES.index(name)] = np.radians(x) if degrees else x
            measured.append(name)
    moving = tuple(n for n in measured if np.ptp(q[:, JOINT_NAMES.index(n)]) > 1e-9)
    stamps = 1_000_000_000 + np.round((t - t[0]) * 1e9).astype(np.int64)
    return Recording(path.stem, stamps, q, tuple(measured), moving, source)


def recordings(extra: Path | None = None) -> list[Recording]:
    """The committed recordings (benchmarks/data), and those in `extra` (an opensim-models
    checkout: not committed here, see benchmarks/data/README.md)."""
    out = [recording(HERE / "data" / "arm26_InverseKinematics.mot",
                     "opensim-models Tutorials/Computed_Muscle_Control (CC BY 3.0), 120 Hz")]
    if extra is not None:
        for rel, src in (("Pipelines/Hamner/outputReference/ResultsIK/subject02_running_ik.mot",
                          "opensim-models Hamner running IK, 60 Hz"),
                         ("subject02_running_ik.mot", "opensim-models Hamner running IK, 60 Hz"),
                         ("subject01_run_IK.mot", "opensim-models Rajagopal running IK, 100 Hz")):
            p = extra / rel
            if p.exists() and not any(r.name == p.stem for r in out):
                out.append(recording(p, src))
    return out


def third_difference_noise(q: np.ndarray) -> np.ndarray:
    """Per column: the white-noise level third differences give (rad): sqrt(mean(d3^2) / 20)."""
    d3 = np.diff(q, 3, axis=0)
    return np.sqrt(np.mean(d3**2, axis=0) / 20.0)


GROUP_IDX = {g: [JOINT_NAMES.index(d) for d in dofs] for g, dofs in DOF_GROUPS.items()}
