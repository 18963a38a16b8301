"""Kalman filter with a white-jerk (constant-acceleration) model per joint, one shared covariance.

State per joint x = [q, qd, qdd]; between samples dt apart
    x' = F x + w,  F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]],
    w = integrated white jerk of spectral density S (kalman_jerk_psd, rad^2/s^5):
    Q = S [[dt^5/20, dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]].
Measurement: the position (noise std r), and with velocities given also the velocity
(noise std r_v), fused as a second measurement row.

Gains: all joints share dt, the noise levels and the model, hence one 3x3 covariance P
for all of them; it is propagated per sample (P' = F P F^T + Q, then the measurement
update) in plain float arithmetic, ~40 multiplications (a few us), and the update is two
small matrix products on the stacked state X = [q; qd; qdd] (3, n): X = F X (predict),
X += K E (correct with the innovations E). So every sample gets the exact gain of its own
dt and the current noise belief: a jittered stream, a dropped sample (one 2 dt step) or a
new noise estimate costs nothing extra (gains cached by dt bucket, the first version,
missed on every jittered 1 kHz stream: Riccati solves in the callback; README). Start: P is the steady-state
covariance of the first step's dt (solve_discrete_are, once per estimator; a reset keeps
P, since the sensor did not change), so a stream that starts at rest has no start-up
transient (a time-varying warm-up from a wide prior would put the noise of raw
differences into the first estimates); one that starts in motion converges with the
filter's own time constant (about the qdd lag). When the online noise belief moves more
than 12 % from the one P was seated at, P is seated again at the new steady state (one
solve; a handful per stream: at the start, at the first estimate, when the sensor
changes): the propagation alone would take the filter's time constant to follow, and
meanwhile the gate below would judge with the old, too small, uncertainty. State at the
start and after a reset: q = the first sample, qd = 0 (or the given velocity), qdd = 0;
warm after 3 samples (2 with velocities), as the backward difference.

Noise: kalman_noise_deg > 0 fixes the position noise std (degrees); 0 estimates it online:
per joint an exponentially weighted mean (time constant 2 s) of the squared third
difference of the raw positions (= 20 r^2 for white noise when the signal is smooth;
above ~400 Hz from one window of consecutive samples in 8, which is plenty: only the
samples of a window are copied, ~2 us per sample saved at 1 kHz),
the median over joints every 0.25 s (most joints are still at any time, so motion hardly
biases it), floored at kalman_noise_floor_deg. Velocity noise likewise from the given
velocities, or fixed by kalman_velocity_noise_dps: v0 - v1 - rho (v1 - v2), rho = dt0/dt1
the ratio of the last two steps, which is zero for any constant acceleration at any stamp
spacing and has variance (1 + (1 + rho)^2 + rho^2) r_v^2 for white noise (6 r_v^2 when
rho = 1). The plain second difference is not zero under stamp jitter: it takes the
acceleration times the jitter for noise (100 rad/s^2 x 0.2 ms = 1.1 deg/s on exact
velocities).

Lag: the model is exact for constant acceleration, so q and qd have no delay at low
frequency; under a constant jerk j the acceleration estimate settles at qdd - j d, d the
lag of qdd, computed by lag() from the steady-state error of the gain in use.
predict(t) extrapolates the model (constant acceleration) from the last update.

Discontinuities (a posture that jumps in one sample, as between two movements that
trajectory_publisher plays back to back, or a tracker that re-acquires a hand): a sample
whose position innovation on any joint exceeds GATE_SIGMAS x sigma + GATE_FLOOR_RAD (sigma:
the innovation std of this sample, sqrt(P_qq + r^2) of its prior) is a discontinuity: the filter is
re-initialised from that sample as at the start (q = the sample, qd = 0 or the given
velocity, qdd = 0; warm again after 3 (2) samples), the sample stays out of the noise
statistics (their difference rings restart from it), and `discontinuities` counts it.
Without this, the jump's innovation rings through the filter for its whole time constant
and its 3rd differences inflate the online noise, so the filter then smooths and lags a
whole movement (check_bag's pipeline NRMSE up to 342 % on the back-to-back replay).
The gate is armed once the online noise has had its first estimate (at once with a fixed
noise), so a noisy stream is never judged against the 0.5 deg default belief. The floor
(0.15 rad = 8.6 deg) is 2.3x the largest genuine innovation of the library's movements at
20 Hz (0.065 rad, exact positions); the threshold stays under the smallest jump between two
consecutive movements (0.39 rad) at 1 kHz exact (0.15 rad) and at 100 Hz with 0.5 deg noise
(0.31 rad). The hardest genuine motion measured, 130 deg in 0.3 s (6 samples) at 20 Hz
with 5 deg noise, where the filter lags most of the movement, reached 10 sigma over the
floor: hence 12 sigma (test_estimation.py runs it; the library's 0.5 s movements need
< 4 sigma). Jumps smaller than the threshold (at 20 Hz or with noise of degrees) pass as
motion: the filter then converges with its own time constant, as before. At most
GATE_MAX_PER_WINDOW discontinuities per noise window (0.25 s): more are not jumps but a
sensor that got noisier, and are filtered normally so the noise estimate can follow.

Defaults, from benchmarks/estimation.py (65 movements, positions only, 1/4 of them for the
tuning runs): kalman_jerk_psd = 3e3 was the best or within 3 % of the best of {1e3, 3e3,
1e4, 3e4} at every rate (30-1000 Hz) and noise (0.1-2 deg); the noise is estimated online
because a fixed 0.5 deg belief (psd 1e4) was 2.5 x worse at 2 deg noise (elbow global NRMSE
0.40 vs 0.17 at 100 Hz); at 0.1 deg it was 9 % better than online with psd 1e4, but psd 3e3
online beats both there (0.068). Tried and left out: a constant-jerk (white snap)
model (worse at every tested point) and per-joint switching to a 10x quieter model while a
joint's innovations fit it (3 % better, 10 us more per sample).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import solve_discrete_are

from .base import SettingSpec, StateEstimator

_RESEAT = math.log(1.12)  # a noise belief this much (12 %) off P's seat re-seats P
_NOISE_TAU_S = 2.0
_NOISE_EVERY_S = 0.25
_NOISE_STRIDE = 8  # above ~400 Hz the noise statistics use one difference per 8 samples:
_NOISE_FAST_DT_S = 2.0e-3  # from stride 1 to 8 below this dt,
_NOISE_SLOW_DT_S = 3.0e-3  # back to 1 above this one
GATE_SIGMAS = 12.0  # discontinuity: innovation > GATE_SIGMAS sigma + GATE_FLOOR_RAD (any joint)
GATE_FLOOR_RAD = 0.15
_FLOOR2 = GATE_FLOOR_RAD**2
GATE_MAX_PER_WINDOW = 3  # per _NOISE_EVERY_S; beyond, crossings are noise (see the docstring)


def transition(dt: float) -> np.ndarray:
    return np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])


def observation(velocity_given: bool) -> np.ndarray:
    """H: the position is measured, and the velocity when the message carries it."""
    return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) if velocity_given else np.array([[1.0, 0.0, 0.0]])


def process_noise(dt: float, psd: float) -> np.ndarray:
    d2, d3 = dt * dt, dt * dt * dt
    return psd * np.array([[d2 * d3 / 20, d2 * d2 / 8, d3 / 6],
                           [d2 * d2 / 8, d3 / 3, d2 / 2],
                           [d3 / 6, d2 / 2, dt]])


def steady_state(dt: float, r: float, r_v: float | None, psd: float) -> tuple[np.ndarray, np.ndarray]:
    """(gain K (3, m), prior covariance P) of the converged filter; m = 1 or 2 measurements.

    Solved in units of r (positions / r) so the equation is well scaled for any noise.
    """
    f = transition(dt)
    q = process_noise(dt, psd / (r * r))
    h = observation(r_v is not None)
    rm = np.eye(1) if r_v is None else np.diag([1.0, (r_v / r) ** 2])
    p = solve_discrete_are(f.T, h.T, q, rm)
    k = p @ h.T @ np.linalg.inv(h @ p @ h.T + rm)
    return k, p * (r * r)


def measurement_update(m: tuple[float, ...], r2: float, rv2: float | None
                       ) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(gain, posterior) from the prior M (m00 m01 m02 m11 m12 m22), position variance r2
    and, velocities given, velocity variance rv2. Gain: (k0, k1, k2) for positions only,
    else row by row (k00, k01, k10, k11, k20, k21); posterior in M's layout."""
    m00, m01, m02, m11, m12, m22 = m
    s00 = m00 + r2
    if rv2 is None:
        k0, k1, k2 = m00 / s00, m01 / s00, m02 / s00
        return (k0, k1, k2), (m00 - k0 * m00, m01 - k0 * m01, m02 - k0 * m02,
                              m11 - k1 * m01, m12 - k1 * m02, m22 - k2 * m02)
    s11 = m11 + rv2
    det = s00 * s11 - m01 * m01
    i00, i01, i11 = s11 / det, -m01 / det, s00 / det  # S^-1
    # K = M H^T S^-1: row i is (m_i0, m_i1) S^-1
    k00, k01 = m00 * i00 + m01 * i01, m00 * i01 + m01 * i11
    k10, k11 = m01 * i00 + m11 * i01, m01 * i01 + m11 * i11
    k20, k21 = m02 * i00 + m12 * i01, m02 * i01 + m12 * i11
    return (k00, k01, k10, k11, k20, k21), (
        m00 - k00 * m00 - k01 * m01, m01 - k00 * m01 - k01 * m11, m02 - k00 * m02 - k01 * m12,
        m11 - k10 * m01 - k11 * m11, m12 - k10 * m02 - k11 * m12, m22 - k20 * m02 - k21 * m12)


class KalmanCA(StateEstimator):
    """White-jerk Kalman filter per joint with cached steady-state gains; see the module docstring."""

    name = "kalman"
    settings = (
        SettingSpec("kalman_jerk_psd", 3e3, "rad^2/s^5",
                    "white-jerk spectral density of the model (higher: faster, noisier)",
                    lo=1e-3, hi=1e12),
        SettingSpec("kalman_noise_deg", 0.0, "deg",
                    "position noise std; 0 = estimate online", lo=0.0, hi=90.0),
        SettingSpec("kalman_velocity_noise_dps", 0.0, "deg/s",
                    "velocity noise std (velocities given); 0 = estimate online", lo=0.0, hi=1e5),
        SettingSpec("kalman_noise_floor_deg", 0.01, "deg",
                    "lowest noise the online estimate may believe (and the velocity floor in deg/s)",
                    lo=1e-6, hi=90.0),
    )

    def __init__(self, n: int, settings):
        super().__init__(n, settings)
        v = self.values
        self.psd = v["kalman_jerk_psd"]
        self._floor = math.radians(v["kalman_noise_floor_deg"])
        self._fixed_r = math.radians(v["kalman_noise_deg"]) or None
        self._fixed_rv = math.radians(v["kalman_velocity_noise_dps"]) or None
        self._r_v_default = self._fixed_rv or math.radians(1.0)  # before any estimate: 1 deg/s
        self._r_default = self._fixed_r or math.radians(0.5)  # before any estimate: 0.5 deg
        # The filter state X = [q; qd; qdd] (3, n); one sample is X = F X, X += K E with
        # matrix products on the stacked rows (a few numpy calls whatever the joint count).
        self._X = np.zeros((3, n))
        self._T3 = np.zeros((3, n))
        self._F = np.eye(3)
        self._E = np.zeros((2, n))  # innovations: position, velocity
        self._K = np.zeros((3, 2))  # the gain of the last sample (one or two columns in use)
        self._P: tuple[float, ...] | None = None  # posterior covariance p00 p01 p02 p11 p12 p22
        self._seat = (1.0, 1.0)  # the noise (r, r_v) P was last seated at the steady state for
        self._K1 = self._K[:, :1]  # positions only: one column (a view, made once)
        self._E1 = self._E[:1]
        self._out = np.zeros((3, n))  # the outputs q, qd, qdd are its rows
        self.q, self.qd, self.qdd = self._out
        self._tmp = np.zeros(n)
        # online noise: rings of raw samples; a difference is one product with rotated weights
        self._ring = np.zeros((4, n))
        self._vring = np.zeros((3, n))
        self._tmp2 = np.zeros(n)
        self._d3 = [np.roll([-1.0, 3.0, -3.0, 1.0], h + 1) for h in range(4)]  # newest at h
        self._vdt = 0.0  # the step before the last: rho of the velocity difference
        self._ms = np.zeros(n)
        self._ms_v = np.zeros(n)
        self._r, self._r_v = self._r_default, self._r_v_default
        self._armed = self._fixed_r is not None  # online noise: after its first estimate
        self._gate_left = GATE_MAX_PER_WINDOW
        self.discontinuities = 0  # samples that re-initialised the filter (the node may report it)
        self._qfrom = self._vfrom = 0  # ring counts at the last restart: no difference across it
        self._dt = 1e-3
        self._stride = 1
        self.reset()

    # -- state ----------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the motion; the noise estimates stay (a stamp jump does not change the sensor)."""
        self._t_ns = None
        self._count = 0
        self._qcount = 0
        self._vcount = 0
        self._qfrom = self._vfrom = 0
        self._since_noise = 0.0

    def noise(self) -> float | None:
        return self._r

    def velocity_noise(self) -> float | None:
        return self._r_v

    def _start_covariance(self, dt: float, vel: bool) -> None:
        """P = the steady-state posterior covariance at dt (see the module docstring)."""
        k, m = steady_state(dt, self._r, self._r_v if vel else None, self.psd)
        self._seat = (self._r, self._r_v)
        h = np.eye(3)[: k.shape[1]]
        post = m - k @ (h @ m)
        self._P = tuple(float(post[i, j]) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))

    def _prior(self, dt: float) -> tuple[float, ...]:
        """M = F P F^T + Q at dt (m00 m01 m02 m11 m12 m22), plain floats: ~30 multiplications,
        cheaper than numpy calls on 3x3 arrays."""
        p00, p01, p02, p11, p12, p22 = self._P
        h = 0.5 * dt * dt
        a0, a1, a2 = p00 + dt * p01 + h * p02, p01 + dt * p11 + h * p12, p02 + dt * p12 + h * p22
        b1, b2 = p11 + dt * p12, p12 + dt * p22
        s = self.psd * dt
        return (a0 + dt * a1 + h * a2 + s * h * h / 5,  # Q: S dt^5/20
                a1 + dt * a2 + s * h * dt / 4,  # S dt^4/8
                a2 + s * h / 3,  # S dt^3/6
                b1 + dt * b2 + s * h * 2 / 3,  # S dt^3/3
                b2 + s * dt / 2,  # S dt^2/2
                p22 + s)  # S dt

    def _covariance(self, dt: float, vel: bool) -> None:
        """One step of the shared covariance: the gain into self._K, the posterior into self._P."""
        k, self._P = measurement_update(self._prior(dt), self._r * self._r,
                                        self._r_v * self._r_v if vel else None)
        g = self._K
        if vel:
            g[0, 0], g[0, 1], g[1, 0], g[1, 1], g[2, 0], g[2, 1] = k
        else:
            g[0, 0], g[1, 0], g[2, 0] = k

    # -- update ---------------------------------------------------------------------------
    def update(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> bool:
        self.check(t_ns, q, qd)
        vel = qd is not None
        x = self._X
        if self._t_ns is not None:
            dt = (t_ns - self._t_ns) * 1e-9
            f, t3, e = self._F, self._T3, self._E
            f[0, 1] = f[1, 2] = dt
            f[0, 2] = 0.5 * dt * dt
            np.dot(f, x, out=t3)  # predict
            np.subtract(q, t3[0], out=e[0])
            # the gate; the sum of squares (one call) rules most samples out: threshold > floor
            if self._armed and self._gate_left and float(np.dot(e[0], e[0])) > _FLOOR2:
                if self._P is None:
                    self._start_covariance(dt, vel)
                gate = GATE_SIGMAS * math.sqrt(self._prior(dt)[0] + self._r * self._r) + GATE_FLOOR_RAD
                np.abs(e[0], out=self._tmp)
                if self._tmp.max() > gate:  # a discontinuity: start again from here
                    self._gate_left -= 1
                    self.discontinuities += 1
                    self._qfrom, self._vfrom = self._qcount, self._vcount
                    self._since_noise += dt
                    self._t_ns = None
        if self._t_ns is None:
            self._t_ns = t_ns
            np.copyto(x[0], q)
            if vel:
                np.copyto(x[1], qd)
            else:
                x[1].fill(0.0)
            x[2].fill(0.0)
            np.copyto(self._out, x)
            self._count = 1
            self._noise_input(q, qd)
            return False
        self._dt = dt
        self._t_ns = t_ns
        stride = self._stride  # noise statistics from every 8th sample above ~400 Hz (hysteresis)
        if (dt < _NOISE_FAST_DT_S) if stride == 1 else (dt > _NOISE_SLOW_DT_S):
            self._stride = _NOISE_STRIDE if stride == 1 else 1
            self._qfrom, self._vfrom = self._qcount, self._vcount  # fresh windows at the new stride
        self._noise_input(q, qd)
        self._since_noise += dt
        if self._since_noise >= _NOISE_EVERY_S:
            self._since_noise = 0.0
            self._gate_left = GATE_MAX_PER_WINDOW
            if self._online:
                self._update_noise(vel)
        if self._P is None:
            self._start_covariance(dt, vel)
        self._covariance(dt, vel)
        if vel:
            np.subtract(qd, t3[1], out=e[1])
            np.dot(self._K, e, out=x)  # correct
        else:
            np.dot(self._K1, self._E1, out=x)
        x += t3
        np.copyto(self._out, x)  # outputs are copies: predict() may overwrite them
        self._count += 1
        return self._count >= (2 if vel else 3)

    # -- online noise ---------------------------------------------------------------------
    @property
    def _online(self) -> bool:
        return self._fixed_r is None or self._fixed_rv is None

    def _noise_input(self, q: np.ndarray, qd: np.ndarray | None) -> None:
        """Per joint mean squares of the 3rd difference of positions, and of the velocities' 2nd
        difference scaled to r_v^2 (see the module docstring)."""
        if not self._online:
            return
        tmp, stride = self._tmp, self._stride
        if self._fixed_r is None:
            c = self._qcount = self._qcount + 1
            h = (c - 1) % 4
            if (-c) % stride < 4:  # one of the 4 samples whose difference is taken (all at stride 1)
                np.copyto(self._ring[h], q)
                if c % stride == 0 and c - self._qfrom >= 4:  # q - 3 q1 + 3 q2 - q3
                    np.dot(self._d3[h], self._ring, out=tmp)
                    tmp *= tmp
                    self._ms_add(self._ms, tmp, c - 3)
        if qd is not None and self._fixed_rv is None:
            c = self._vcount = self._vcount + 1
            h = (c - 1) % 3
            vdt, self._vdt = self._vdt, self._dt  # the step before this one, and this one
            if (-c) % stride < 3:
                np.copyto(self._vring[h], qd)
                if c % stride == 0 and c - self._vfrom >= 3:
                    rho = self._dt / vdt  # v0 - v1 - rho (v1 - v2): 0 for constant acceleration
                    v1, v2 = self._vring[(h - 1) % 3], self._vring[(h - 2) % 3]
                    np.subtract(v1, v2, out=self._tmp2)
                    self._tmp2 *= rho
                    np.subtract(qd, v1, out=tmp)
                    tmp -= self._tmp2
                    tmp *= tmp
                    tmp *= 1.0 / (1.0 + (1.0 + rho) ** 2 + rho * rho)  # variance r_v^2 (white noise)
                    self._ms_add(self._ms_v, tmp, c - 2)

    def _ms_add(self, ms: np.ndarray, sq: np.ndarray, k: int) -> None:
        """Running mean over the first samples, then exponential (time constant _NOISE_TAU_S)."""
        a = min(1.0, max(self._stride / k, self._stride * self._dt / _NOISE_TAU_S))
        sq -= ms
        sq *= a
        ms += sq

    def _update_noise(self, vel: bool) -> None:
        if self._fixed_r is None and self._qcount >= 7:
            self._r = max(math.sqrt(max(float(np.median(self._ms)), 0.0) / 20.0), self._floor)
            self._armed = True
        if vel and self._fixed_rv is None and self._vcount >= 6:
            self._r_v = max(math.sqrt(max(float(np.median(self._ms_v)), 0.0)), self._floor)
        r, r_v = self._seat
        if abs(math.log(self._r / r)) > _RESEAT or (vel and abs(math.log(self._r_v / r_v)) > _RESEAT):
            self._P = None  # re-seated at the next step: the steady state of the new belief

    # -- description ------------------------------------------------------------------------
    def lag(self, dt: float, velocity_given: bool) -> dict[str, float]:
        """q, qd: 0 (exact for constant acceleration); qdd: steady-state error / jerk."""
        rv2 = self._r_v * self._r_v if velocity_given else None
        if self._P is None:  # no sample yet: the steady-state gain it will start with
            k, _ = steady_state(dt, self._r, None if rv2 is None else self._r_v, self.psd)
        else:  # the gain the filter uses at this dt now (no Riccati solve on a node's thread)
            g, _ = measurement_update(self._prior(dt), self._r * self._r, rv2)
            k = np.array(g).reshape(3, 1 if rv2 is None else 2)
        h = observation(velocity_given)
        f = transition(dt)
        g = np.array([dt**3 / 6, dt**2 / 2, dt])  # true-state increment per unit jerk, on top of F x
        ikh = np.eye(3) - k @ h
        # e = est - true after update; e' = (I - K H)(F e - g j)  ->  e = -(I - (I-KH)F)^-1 (I-KH) g j
        e = -np.linalg.solve(np.eye(3) - ikh @ f, ikh @ g)
        return {"q": 0.0, "qd": 0.0, "qdd": float(-e[2])}

    def describe(self, dt: float, velocity_given: bool = False) -> dict:
        out = super().describe(dt, velocity_given)
        out["noise_online"] = self._fixed_r is None
        out["discontinuities"] = self.discontinuities
        out["gate_rad"] = {"sigmas": GATE_SIGMAS, "floor": GATE_FLOOR_RAD}
        if velocity_given:
            out["velocity_noise_rad_s"] = self._r_v
        return out
