"""Kalman filter with a white-jerk (constant-acceleration) model, per-joint noise.

The parts, each in its own module and tested alone: the model and its discretisation
(ca_model.py), the per-joint noise estimator (noise.py), the jump gate (gate.py), the
fixed-lag smoother (smoother.py), and two mixins of the filter: its noise groups and their
covariance recursions (noise_groups.py) and its per-joint noise belief (noise_belief.py);
the per-sample arithmetic (predict, innovations, correction) runs as two compiled calls
where the C extension is built (kalman_step.py), numpy's way otherwise, and so does the
step of noise groups seated at their steady state (kalman_step.Gains, noise_groups.py).
This module is the filter that wires them.

Filter: state X = [q; qd; qdd] (3, n); per sample X = F X (predict), X += K (.) E (correct
with the innovations E; K per joint). The gain of a joint depends on dt, the psd and its own
noise (r, r_v). Joints are grouped by noise level (bins a factor sqrt(2) apart, with
hysteresis: a joint changes bin only when its estimate leaves its bin by 0.6 bin), and each
group carries one covariance recursion in plain floats (ca_model.prior/measurement_update,
a few us), so every sample gets the exact gain of its own dt: a jittered stream, a dropped
sample or a new noise estimate cost nothing extra. A group whose recursion has converged at
a repeating dt skips it (a uniform stream costs the recursion only at its start). A new
group is seated at the steady state of its noise (one Riccati solve, a few per stream).

Restart (the stream's first sample, reset(), the gate's discontinuity): the state starts
from one sample (q the sample, q̇ 0 or the given velocity, q̈ 0) and every group is seated
diffuse on (q̇, q̈) (ca_model.restart_posterior: the spread a white jerk gives them in
1 s, measured once by the sample), so the next samples teach it q̇ and q̈ (a least-squares
fit at first); once its (q̇, q̈) covariance is within 1e-3 of the steady state it is seated
there and stops again (noise_groups.py: 40-150 group steps positions only, 5-20 with
velocities, at 1 kHz). Why: seated at the steady state, the filter trusted its zeros as much
as a converged estimate: an exact library movement, positions only, 1 kHz, reset mid-
movement: q̈ error over the next 150 ms 121 % of its range, 5.2 % now (never restarted:
9.1 %; test_estimation_restart.py). The first sample too: a stream that starts mid-movement
gets the same (q̈ error over its first 150 ms, positions only: exact 63 -> 15 %, 0.5 deg
69 -> 24 %), and one that starts from rest loses nothing (exact: 0 % both; 0.5 deg:
37 -> 20 %, /tmp sweeps of the library's movements 3, 19, 55). Why per joint (issue 16): one level
shared by all joints (the median, as in the first version) is the still joints' zero when a
lab measures the arm and holds the fingers: the moving joints then trusted their noise
(elbow torque NRMSE 18 x the causal 6 Hz Butterworth's). A held or exact joint believes the
floor and is passed through; a noisy one is smoothed by its own noise.

Noise: kalman_noise_deg > 0 fixes the position noise of every joint (degrees); 0 estimates
it per joint online (noise.py: the level around 10 Hz, above the movement's band, white or
coloured), floored at kalman_noise_floor_deg and updated every 0.25 s. Positions only, a joint
whose band level exceeds 1.5 x its white level (third differences of consecutive samples,
near Nyquist, where no movement is) has coloured noise or movement content around 10 Hz
(IK and soft-tissue artefact; running IK's impacts), and its belief is capped where the
filter's bandwidth, (psd / (r^2 dt))^(1/6), falls to kalman_min_bandwidth_hz (7 Hz: 0.37
deg at 100 Hz): the offline practice keeps everything below 6 Hz, and a causal filter that
smooths into that band is wrong against it (two running IK recordings, torque NRMSE against
the practice over the causal 6 Hz Butterworth's: 1.2-1.3 x uncapped, 1.01 / 1.04 x capped at
6 Hz, 0.95 / 0.86 x at 8 Hz; the synthetic mocap IK sensor against its truth prefers 6-7 Hz:
elbow / pro-sup 0.75 / 0.70-0.74 x, 0.77 / 0.87 x at 8 Hz; 7 Hz serves both; /tmp sweeps of
benchmarks/estimation_zoo.py, whose committed output states the default's numbers). With a
delay (delay_s > 0) the cap is off: the smoother sees each sample from both sides, as the
practice does (mocap IK 100 Hz, delay 50 ms: 1.27 / 1.04 x the offline floor uncapped,
1.43 / 1.62 x capped at 8 Hz).
The practice filter (issue 29; estimator.practice_filter, on by default; causal, positions
only): on raw recordings of real arm movements the torques are judged against the offline
practice (6 Hz zero-phase + derivatives) and nearly all of their error is q̈'s; a noisy joint
that passes content the practice removes (coloured noise, or a model wider than 6 Hz) gets
as q̈ the blend of the model's and a fixed causal filter's designed on such recordings
(practice_fir.py), weighted per joint by what the practice says of each (practice_blend.py;
which joints and how: practice_output.py). q and q̇ stay the model's.
White noise (band and white levels alike: a camera, a
glove, an encoder) is noise at every frequency and is smoothed as strongly as it says.
The jump
gate judges with the noise as measured. Velocity noise
likewise from given velocities, or fixed by kalman_velocity_noise_dps.

Gate (gate.py): a joint whose innovation exceeds 4 sigma + 1 deg is held back one sample;
an outlier (back at the next sample) is dropped and counted (`outliers`), a genuine sample
is restored exactly, and one beyond 12 sigma + 0.15 rad that stays is a discontinuity: the
filter restarts from it (q = the sample, qd = 0 or the given velocity, qdd = 0, seated
diffuse as above; warm after 3 (2) samples; `discontinuities`). A withheld sample's output
is the prediction, except
beyond the discontinuity threshold on exact input (the held joints' white noise level at the
floor; causal output): there it is the sample as a restart gives it (two movements played
back to back jump 0.39-2.3 rad: the old posture for one sample was a pipeline error of
995 % on a DOF that barely moves in the next movement). A noisy sensor's sample beyond it
(a 20 deg marker swap) still outputs the prediction.

Delay (estimator.delay_s, 0 = causal): the fixed-lag smoothed estimate of the sample delay_s
back, stamped with its stamp (delayed_output.py).

Lag (causal): the model is exact for constant acceleration, so q and qd have no delay at
low frequency; under a constant jerk j the acceleration estimate settles at qdd - j d, d
from the steady-state error of the gain in use (ca_model.qdd_lag; the noisiest group's).
predict(t) extrapolates the model (constant acceleration) from the last estimate.

Covariance (for torque uncertainty): `covariance()` returns the posterior covariance of
(q, qd, qdd) per joint, (n, 3, 3), of the estimate the filter outputs (the smoothed one
with a delay); `innovations` holds the last innovations, `noise_per_joint()` the noise
each joint believes.

Defaults, from benchmarks/estimation.py: kalman_jerk_psd = 3e3 was the best or within 3 %
of the best of {1e3, 3e3, 1e4, 3e4} at every rate (30-1000 Hz) and noise (0.1-2 deg) with
white noise (the noise estimate is unbiased there, as the first version's was).
"""

from __future__ import annotations

import math

import numpy as np

from . import ca_model, kalman_step, practice_lag
from .base import SettingSpec, StateEstimator
from .ca_model import process_noise, steady_state, transition  # noqa: F401 - public API
from .compiled import BindsCompiled
from .delayed_output import DelayedOutput
from .gate import MAX_PER_WINDOW as GATE_MAX_PER_WINDOW  # noqa: F401 - public API
from .gate import JumpGate
from .noise import NoiseEstimator
from .noise_belief import NoiseBelief
from .noise_groups import Col, NoiseGroup, NoiseGroups, _Group  # noqa: F401 - NoiseGroup: public API
from .practice_blend import PracticeBlend
from .practice_fir import PracticeFIR
from .practice_lag import PracticeLag
from .practice_output import BAND_HZ, PracticeOutput

NOISE_EVERY_S = 0.25
MAX_DELAY_S = 0.2


#: lag(): the gain in use describes a step within this fraction of the one asked about (the
#: groups keep a gain while the step stays within noise_groups.JITTER of the period)
LAG_DT_TOL = 0.25


class KalmanCA(DelayedOutput, PracticeOutput, NoiseGroups, NoiseBelief, BindsCompiled,
               StateEstimator):
    """White-jerk Kalman filter, per-joint noise; see the module docstring."""

    name = "kalman"
    settings = (
        SettingSpec("kalman_jerk_psd", 3e3, "rad^2/s^5",
                    "white-jerk spectral density of the model (higher: faster, noisier)",
                    lo=1e-3, hi=1e12),
        SettingSpec("kalman_noise_deg", 0.0, "deg",
                    "position noise std of every joint; 0 = estimate each joint's online",
                    lo=0.0, hi=90.0),
        SettingSpec("kalman_velocity_noise_dps", 0.0, "deg/s",
                    "velocity noise std (velocities given); 0 = estimate online", lo=0.0, hi=1e5),
        SettingSpec("kalman_noise_floor_deg", 0.01, "deg",
                    "lowest noise the online estimate may believe (and the velocity floor in deg/s)",
                    lo=1e-6, hi=90.0),
        SettingSpec("kalman_min_bandwidth_hz", 7.0, "Hz",
                    "causal, positions only, coloured noise: never smooth below this band (keeps "
                    "what the offline 6 Hz practice keeps): the belief is capped where the "
                    "filter's bandwidth reaches it; 0 = off", lo=0.0, hi=1000.0),
        SettingSpec("practice_filter", 1.0, "",
                    "causal, positions only: the share of the practice filter's blend in the q̈ of "
                    "a noisy joint that the model filters wider than 6 Hz or whose noise is "
                    "coloured (the blend of the model's q̈ and a causal kernel's designed on real "
                    "arm movements, weighted per joint against the offline practice: "
                    "practice_output.py); 1 = the blend, 0 = the model's own q̈ on every joint",
                    lo=0.0, hi=1.0),
        SettingSpec("delay_practice_hz", 6.0, "Hz",
                    "with delay_s >= 0.04 s, positions only: the delayed estimate of a noisy joint with "
                    "coloured noise or a model wider than this band moves towards the offline "
                    "practice's (zero-phase low-pass at this band + derivatives) from the samples "
                    "the delay makes available and the filter's prediction of the rest, by a weight "
                    "measured online (practice_lag.py); 0 = the model's fixed-lag smoother",
                    lo=0.0, hi=1000.0),
        SettingSpec("delay_s", 0.0, "s",
                    "output the fixed-lag smoothed estimate of the sample this far back, "
                    "stamped with its stamp (0 = causal)", lo=0.0, hi=MAX_DELAY_S),
    )

    def __init__(self, n: int, settings):
        super().__init__(n, settings)
        v = self.values
        self.psd = v["kalman_jerk_psd"]
        self._floor = math.radians(v["kalman_noise_floor_deg"])
        self._fixed_r = math.radians(v["kalman_noise_deg"]) or None
        self._fixed_rv = math.radians(v["kalman_velocity_noise_dps"]) or None
        self.delay_s = v["delay_s"]
        # per-joint noise belief (rad, rad/s); before any estimate: 0.5 deg, 1 deg/s
        self._r = np.full(n, self._fixed_r or math.radians(0.5))
        self._r_gate = self._r.copy()
        self._wmin = 2.0 * math.pi * v["kalman_min_bandwidth_hz"]
        self._rv = np.full(n, self._fixed_rv or math.radians(1.0))
        self._X = np.zeros((3, n))
        self._T3 = np.zeros((3, n))
        self._F = np.eye(3)
        self._E = np.zeros((2, n))  # innovations: position, velocity
        self.innovations = self._E
        self._Kp = np.zeros((3, n))  # per-joint gains: position, velocity innovation
        self._Kv = np.zeros((3, n))
        self._sig = np.zeros(n)
        self._tmp = np.zeros(n)
        self._tmp3 = np.zeros((3, n))
        self._out = np.zeros((3, n))
        self.q, self.qd, self.qdd = self._out
        self.noise_estimator = NoiseEstimator(n)
        self.gate = JumpGate(n)
        self._held_e = np.zeros((2, n))
        self._held_q = np.zeros(n)
        self._held_qd = np.zeros(n)
        self._held_t = 0
        self._groups: list[_Group] = []
        self._groups_version = 0
        self._gidx = np.zeros(n, np.intp)
        self._bins = np.full((2, n), -10**6)
        self._gstate = np.zeros((0, Col.WIDTH))  # the groups' numbers, a row each (noise_groups)
        self._vel: bool | None = None
        self._armed = self._fixed_r is not None
        self._applied = [False, False]  # a measured (position, velocity) noise is in use
        self._dt = 1e-3
        self._smoother = None  # FixedLagSmoother with a delay (delayed_output.py)
        self._smooth_dt = 0.0
        self._first: tuple[int, np.ndarray] | None = None
        self._restarted = False
        self._jump_exact = False
        self._pf_share = v["practice_filter"]
        on = self._pf_share > 0.0 and self.delay_s <= 0.0
        self._pfir = PracticeFIR(n) if on else None  # the practice filter (practice_output.py)
        self._pblend = PracticeBlend(n, BAND_HZ) if on else None
        self._pf_q: np.ndarray | None = None  # the last sample's positions (gate: prediction)
        self._pf_use = np.zeros(n, bool)  # the rule's joints
        self._pf_was = np.zeros(n, bool)
        self._pf_against = np.zeros(n, np.int64)  # answers against, in a row (HOLD_UPDATES)
        self._pf_w = np.zeros(n)  # their share of the blend in q̈, faded in and out
        self._pf_target = np.zeros(n)  # ... towards this (practice_filter on the rule's joints)
        self._pf_d = np.zeros(n)
        self._pstep = None  # the compiled step (practice_output._practice_compiled)
        self._pcompiled = True
        self._pstep_key: tuple | None = None
        lag_band = v["delay_practice_hz"]
        on = lag_band > 0.0 and self.delay_s >= practice_lag.MIN_DELAY_S
        self._plag = PracticeLag(n, lag_band) if on else None
        self._plag_use = np.zeros(n, bool)  # joints whose delayed estimate is the practice's
        self._plag_use_was = np.zeros(n, bool)
        self._plag_against = np.zeros(n, np.int64)
        # the last sample for the noise statistics, taken after the output (learn())
        self._pending = False
        self._pend_t = 0
        self._pend_q = np.zeros(n)
        self._pend_qd = np.zeros(n)
        self._pend_vel = False
        self._bind()
        self.reset()

    COMPILED = ("_fast", "_gfast", "_pstep")  # BindsCompiled: copies and pickles bind their own

    def _bind(self) -> None:
        """Predict, innovations, correction and the copies after it as two compiled calls on
        this filter's arrays (kalman_step.py; None: numpy's way), and the noise groups' step
        (noise_groups.py)."""
        self._fast = kalman_step.bind(self._X, self._T3, self._E, self._Kp, self._Kv, self._out,
                                      self._pend_q, self._pend_qd)
        self._bind_gains()
        self._pstep_key = None  # the practice filter's: at its next use (practice_output.py)

    def __setstate__(self, state: dict) -> None:
        super().__setstate__(state)  # BindsCompiled: its own compiled step
        self.q, self.qd, self.qdd = self._out  # views again (a copy made them arrays of their own)

    # -- public state ---------------------------------------------------------------------
    @property
    def discontinuities(self) -> int:
        return self.gate.discontinuities

    @property
    def outliers(self) -> int:
        return self.gate.outliers

    @property
    def period_s(self) -> float:
        """The last sample period (s) the filter stepped with."""
        return self._dt

    def covariance(self) -> np.ndarray:
        """Posterior covariance of (q, qd, qdd) per joint, (n, 3, 3), of the estimate in
        self.q/qd/qdd (smoothed with a delay; zeros before the first step)."""
        if self._smoother is not None and self._smoother.cov is not None:
            return self._smoother.cov.copy()
        out = np.zeros((self.n, 3, 3))
        for i, g in enumerate(self._groups):
            out[g.idx] = self._group_covariance(i)
        return out

    # -- state ----------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the motion; the noise estimates stay (a stamp jump does not change the sensor).
        The next sample restarts the filter, its groups seated diffuse (module docstring)."""
        self.learn()
        self._t_ns = None
        self._count = 0
        self._since_noise = 0.0
        self.gate.clear()
        self.noise_estimator.restart()
        self._restart_windows()

    def _restart_windows(self) -> None:
        """The windows over past samples that no restart may span: the smoother's, the
        practice lag's and the practice filter's (reset() and the gate's discontinuity)."""
        for part in (self._smoother, self._plag, self._pfir, self._pblend):
            if part is not None:
                part.restart()

    def _start(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> None:
        x = self._X
        self._t_ns = t_ns
        np.copyto(x[0], q)
        if qd is not None:
            np.copyto(x[1], qd)
        else:
            x[1].fill(0.0)
        x[2].fill(0.0)
        self._count = 1
        self._restarted = True  # the groups are seated diffuse at the next step (noise_groups)

    # -- update ---------------------------------------------------------------------------
    def learn(self) -> None:
        """The last sample into the noise statistics (NoiseEstimator.add), deferred by
        update() when no noise update is due: at 1 kHz that is every sample but one in 250,
        and the add is a fifth of update()'s cost, which a node's output need not wait for."""
        if self._pending:
            self._pending = False
            self.noise_estimator.add(self._pend_t, self._pend_q,
                                     self._pend_qd if self._pend_vel else None)

    def update(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> bool:
        if self._pending:
            self.learn()
        self.check(t_ns, q, qd)
        vel = qd is not None
        gate = self.gate
        if self._t_ns is None:
            self._start(t_ns, q, qd)
            self.noise_estimator.add(t_ns, q, qd)
            if self._pfir is not None and qd is None:
                self._practice_push(t_ns, q)
                self._pf_q = q
            return self._output(t_ns, False, vel)
        dt = (t_ns - self._t_ns) * 1e-9
        if vel != self._vel or not self._groups:
            self._regroup(vel, dt)
        x, f, t3, e = self._X, self._F, self._T3, self._E
        predicted = gate.pending
        if predicted:  # the sample before was held back: what was it?
            self._predict(dt)
            np.subtract(q, t3[0], out=e[0])
            genuine = gate.resolve(e[0], self._sig)
            if gate.jump:  # a discontinuity: restart from the held sample, then take this one
                gate.jump = False
                # the noise window continues across the jump, moved by it (held joints)
                self.noise_estimator.shift(self._held_e[0])
                self._restart_windows()
                self._start(self._held_t, self._held_q, self._held_qd if vel else None)
                dt = (t_ns - self._t_ns) * 1e-9
                self._predict(dt)
            elif genuine.any():  # restore its correction exactly: F K e one sample late
                corr = self._tmp3
                np.multiply(self._Kp, self._held_e[0] * genuine, out=corr)
                if vel:
                    corr += self._Kv * (self._held_e[1] * genuine)
                if self._smoother is not None:
                    self._smoother.add_to_previous(corr)
                if self._plag is not None:
                    self._plag.restore_last(genuine, self._held_q)
                if self._pfir is not None:
                    self._pfir.restore_last(genuine, self._held_q)
                t3 += f @ corr
        self._dt = dt
        self._t_ns = t_ns
        self._covariance_step(dt, vel)  # the gains at dt (x and t3 untouched)
        fast = self._fast
        emax = None
        if fast is not None and not predicted:  # predict and innovations: one compiled call
            try:
                emax = fast.predict_innovate(q, qd, dt)
            except (TypeError, ValueError, BufferError):  # not contiguous float64: numpy's way
                pass
        if emax is None:
            if not predicted:
                self._predict(dt)
            np.subtract(q, t3[0], out=e[0])
            if vel:
                np.subtract(qd, t3[1], out=e[1])
        held = self._armed and gate.check(e[0], self._sig, emax)
        if held:
            h = gate.held
            np.copyto(self._held_q, q)
            if vel:
                np.copyto(self._held_qd, qd)
            self._held_t = t_ns
            np.multiply(e, h, out=self._held_e)
            e[:, h] = 0.0
            if gate.jump:  # exact input (the joints' measured noise at the floor): a real jump
                measured = self.noise_estimator.white(self._tmp)  # no movement near Nyquist
                self._jump_exact = bool((measured[h] <= 2.0 * self._floor).all())
        self._since_noise += dt
        due = self._since_noise >= NOISE_EVERY_S
        # the noise statistics take this sample now (a noise update, or no rate yet) or after
        # the output (learn(): a copy, the caller may reuse q and qd)
        defer = not due and self.noise_estimator.period_s
        copied = False  # the copies the compiled correction made: the output, the deferred sample
        if fast is not None:  # correct
            copied = emax is not None and not held  # (q, qd: arrays the step took)
            keep = copied and defer
            fast.correct(vel, q if keep else None, qd if keep and vel else None,
                         copied and self.delay_s <= 0.0)
        else:
            np.multiply(self._Kp, e[0], out=x)
            if vel:
                np.multiply(self._Kv, e[1], out=self._tmp3)
                x += self._tmp3
            x += t3
        self._count += 1
        qin = np.where(gate.held, t3[0], q) if held else q  # a held joint: the prediction
        if self._plag is not None and not vel:
            self._plag.push(t_ns, qin)
        if self._pfir is not None and not vel:
            if not self._pfir.K:  # the first step's period until the nominal is known
                self._pfir.configure(dt)
                self._pblend.configure(dt)
            self._practice_push(t_ns, qin)
            self._pf_q = qin
        if not defer:
            self.noise_estimator.add(t_ns, qin, qd)
        else:
            self._pending = True
            self._pend_t = t_ns
            self._pend_vel = vel
            if not copied:
                np.copyto(self._pend_q, qin)
                if vel:
                    np.copyto(self._pend_qd, qd)
        if due:
            self._since_noise = 0.0
            gate.new_window()
            self._update_noise(vel, dt)
            if self._plag is not None and self.noise_estimator.white_evaluations:
                self._practice_lag_joints()
            if self._pfir is not None and not vel:
                self._practice_filter_joints()
        return self._output(t_ns, self._count >= (2 if vel else 3), vel, copied)

    def _predict(self, dt: float) -> None:
        """t3 = F(dt) x, numpy's way (kalman_step.py does it with the innovations)."""
        f = self._F
        f[0, 1] = f[1, 2] = dt
        f[0, 2] = 0.5 * dt * dt
        np.dot(f, self._X, out=self._T3)

    def _output(self, t_ns: int, warm: bool, vel: bool, copied: bool = False) -> bool:
        """copied: the compiled correction has copied the state into the outputs."""
        if self.delay_s > 0.0:
            return self._output_delayed(t_ns, warm, vel)
        if not copied:
            np.copyto(self._out, self._X)  # outputs are copies: predict() may overwrite them
        if self._pfir is not None and not vel and self._pfir.K:
            self._practice_filter_output(self._pf_q)
        self.stamp_ns = t_ns
        if self.gate.pending and self.gate.jump and self._jump_exact:
            # held beyond the discontinuity threshold: most likely a jump (two movements
            # back to back), so this one output is the sample as a restart would give it
            # (q = the sample, qd = 0 or given, qdd = 0); the state waits for the next
            self.q[:] = self._held_q
            if vel:
                self.qd[:] = self._held_qd
            else:
                self.qd.fill(0.0)
            self.qdd.fill(0.0)
            return False
        return warm

    # -- description ------------------------------------------------------------------------
    def lag(self, dt: float, velocity_given: bool) -> dict[str, float]:
        """q, qd: 0 (exact for constant acceleration); qdd: steady-state error / jerk of the
        noisiest joint's gain (a delay shortens it: the smoothed estimate is centred).

        The gain in use, at the step it was computed for, while that step is within LAG_DT_TOL
        of dt; else the converged filter's at dt (ca_model.steady_gain, cached). The node asks at
        every diagnostics period, on its executor thread, with the stream's last step, which
        jitter moves: a Riccati solve for each new step cost 1-16 ms there (a 1 kHz stream
        with ±10 % jitter, /tmp timing beside a CI run), 1-16 samples held back each second."""
        i = max(range(len(self._groups)), key=lambda i: self._groups[i].r, default=None)
        m = 2 if velocity_given else 1
        k = None if i is None else self._group_gain(i, m)
        at = dt if k is None else float(self._gstate[i, Col.DT])
        if k is None or abs(at - dt) > LAG_DT_TOL * dt:
            at = dt
            k = ca_model.steady_gain(dt, float(self._r.max()),
                             float(self._rv.max()) if velocity_given else None, self.psd)
        d = ca_model.qdd_lag(at, k, velocity_given)
        return {"q": 0.0, "qd": 0.0, "qdd": max(0.0, d - self.delay_s)}

    def describe(self, dt: float, velocity_given: bool = False) -> dict:
        out = super().describe(dt, velocity_given)
        out["noise_online"] = self._fixed_r is None
        out["noise_rad_per_joint"] = [float(x) for x in self._r]
        out["noise_groups"] = len(self._groups)
        out["discontinuities"] = self.discontinuities
        out["outliers"] = self.outliers
        out["delay_s"] = self.delay_s
        out["gate_rad"] = {"outlier": "4 sigma + 1 deg", "discontinuity": "12 sigma + 0.15 rad"}
        if velocity_given:
            out["velocity_noise_rad_s"] = self.velocity_noise()
        return out
