"""A restart mid-movement (issue 29's restart transient): reset() (torque_node on a stamp gap,
an input timeout, an absurd sample) and the jump gate's discontinuity restart start the
filter from one sample with q̇ = 0 (positions only) and q̈ = 0. Seated at the steady
covariance, the filter believed those zeros as much as a converged estimate and took
~150 ms to pull q̈ to the real acceleration (an exact library movement, positions only,
1 kHz: q̈ error 121 % of its range over the 150 ms after the restart, against 7 % for the
filter that never restarted). Seated diffuse (ca_model.restart_posterior) it learns them
from the samples that follow, then stops its recursion again (noise_groups.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from forearm_dynamics import get_movement
from forearm_dynamics.estimation import ca_model, make_estimator
from forearm_dynamics.estimation.noise_groups import Col

pytestmark = pytest.mark.unit

RATE = 1000.0
WINDOW = 150  # samples (ms at 1 kHz) scored after the restart


def _qdd_error(mid: int, restart: str | None, noise_deg: float = 0.0, delay_s: float = 0.0,
               velocities: bool = False) -> float:
    """RMS q̈ error over the WINDOW samples after the restart point (from the first warm
    output on), over q̈'s range, worst moving joint; restart None, "reset" or "jump" (every
    position moves 0.5 rad at the restart point and stays moved: the truth moves with it)."""
    mv = get_movement(mid)
    t = mv.sample_times(RATE)
    q, qd, qdd = mv.evaluate(t)
    i0 = round((mv.hold_before + 0.3 * mv.transition) * RATE)  # accelerating, 0.3 into it
    z = q + math.radians(noise_deg) * np.random.default_rng(mid).standard_normal(q.shape)
    if restart == "jump":
        z[i0:] += 0.5
    est = make_estimator("kalman", q.shape[1], {"delay_s": delay_s})
    out = np.full_like(q, np.nan)
    for i in range(len(t)):
        if restart == "reset" and i == i0:
            est.reset()
        est.update(10**9 + i * 10**6, z[i], qd[i] if velocities else None)
        if est.stamp_ns is not None:
            out[(est.stamp_ns - 10**9) // 10**6] = est.qdd
    w = slice(i0 + 3, i0 + WINDOW)
    assert not np.isnan(out[w]).any()
    moving = np.ptp(qdd, axis=0) > 0
    err = np.sqrt(np.mean((out[w] - qdd[w]) ** 2, axis=0))[moving] / np.ptp(qdd, axis=0)[moving]
    return float(err.max())


@pytest.mark.parametrize("restart", ["reset", "jump"])
@pytest.mark.parametrize("mid", [19, 55])
def test_a_restart_mid_movement_learns_the_acceleration_at_once(mid, restart) -> None:
    """Exact positions at 1 kHz: after a restart mid-movement the q̈ error over the next
    150 ms is within 1.25 x the never restarted filter's over the same 150 ms (worst joint,
    of q̈'s range: never restarted 9.1 %; before the fix reset 121 %, jump 121 %; after 5.2 %,
    9.6 %: the jump restarts one sample later, from the held sample)."""
    never = _qdd_error(mid, None)
    restarted = _qdd_error(mid, restart)
    assert restarted <= 1.25 * never, (restarted, never)


def test_a_restart_of_a_noisy_stream_is_no_worse_than_the_filter_that_never_restarted() -> None:
    """0.5 deg white noise, positions only: 150 ms after a reset() mid-movement the worst
    joint's q̈ error is within 1.5 x the never restarted filter's (35 %; before the fix 74 %,
    2.1 x; after 42 %, 1.19 x)."""
    never = _qdd_error(19, None, noise_deg=0.5)
    restarted = _qdd_error(19, "reset", noise_deg=0.5)
    assert restarted <= 1.5 * never, (restarted, never)


def test_a_delayed_restart_is_no_worse_than_the_causal_filter_that_never_restarted() -> None:
    """delay_s 0.05 (the smoother restarts too): the smoothed q̈ after a reset() is within the
    causal never restarted filter's error (9.1 % of q̈'s range; before the fix 61 %, after
    2.3 %; the delayed filter that never restarted: 1.0 %)."""
    causal_never = _qdd_error(19, None)
    restarted = _qdd_error(19, "reset", delay_s=0.05)
    assert restarted <= causal_never, (restarted, causal_never)


def test_velocities_given_restart_mid_movement() -> None:
    """With velocities (q̇ is the sample's, only q̈ starts at 0) the restart was already
    benign at a measured noise; it stays so."""
    never = _qdd_error(19, None, velocities=True)
    restarted = _qdd_error(19, "reset", velocities=True)
    assert restarted <= 1.1 * never, (restarted, never)


def test_the_covariance_says_so_and_returns_to_the_steady_state() -> None:
    """After a restart covariance() states the larger q̈ uncertainty (the σ reads it), and
    once the recursion is back at the steady state the groups are still again (no cost)."""
    mv = get_movement(19)
    t = mv.sample_times(RATE)
    q, _, _ = mv.evaluate(t)
    est = make_estimator("kalman", q.shape[1], {"kalman_noise_deg": 0.5})
    i0 = round((mv.hold_before + 0.3 * mv.transition) * RATE)
    steps = []
    for i in range(i0):
        est.update(10**9 + i * 10**6, q[i], None)
    steady = est.covariance()[:, 2, 2].copy()
    want = ca_model.to_matrix(ca_model.steady_posterior(1e-3, math.radians(0.5), None, est.psd))
    np.testing.assert_allclose(steady, want[2, 2], rtol=1e-9)
    est.reset()
    for i in range(i0, len(t)):
        est.update(10**9 + i * 10**6, q[i], None)
        if i == i0 + 2:
            assert (est.covariance()[:, 2, 2] > 5.0 * steady).all()  # 7 x (before: 1 x)
        if i > i0:  # the sample after the restart seats the groups diffuse
            steps.append(bool(est._gstate[:, Col.STILL].all()))
    settled = steps.index(True)
    assert 10 < settled < 300, settled  # 0.5 deg at 1 kHz: back at steady after ~150 samples
    assert all(steps[settled:])
    np.testing.assert_allclose(est.covariance()[:, 2, 2], steady, rtol=1e-12)


def test_a_stamp_gap_mid_movement_torques_and_sigma() -> None:
    """The node's way (inverse_dynamics_with_std applies the node's stamp rule: a 0.2 s gap in
    the stamps resets the estimator): exact positions at 1 kHz, 3 s at rest, then a movement
    with 0.2 s missing 0.3 into its transition. Over the 150 ms after the gap the worst
    moving DOF's torque NRMSE is within 1.5 x the gapless stream's over the same samples
    (gapless 9.3 %; before the fix 150 %, 16 x; after 8.3 %), and the σ covers >= 90 % of
    the errors (0.91 before, 0.95 after)."""
    from forearm_dynamics.dynamics import build_model
    from forearm_dynamics.uncertainty import inverse_dynamics_with_std

    arm = build_model()
    mv = get_movement(19)
    t = np.concatenate([np.arange(-3000, 0) / RATE, mv.sample_times(RATE)])
    q, qd, qdd = mv.evaluate(t)
    i0 = 3000 + round((mv.hold_before + 0.3 * mv.transition) * RATE)
    truth = arm.inverse_dynamics_batch(q, qd, qdd)
    moving = np.ptp(truth, axis=0) > 1e-6

    def window_error(keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        out = inverse_dynamics_with_std(arm, t[keep], q[keep])
        j0 = int(np.searchsorted(t[keep], t[i0]))
        w = slice(j0, j0 + WINDOW)
        return out.tau[w] - truth[keep][w], out.std[w]

    gap = np.ones(len(t), bool)
    gap[i0 - 200:i0] = False
    e_gap, s_gap = window_error(gap)
    e_ref, _ = window_error(np.ones(len(t), bool))
    span = np.ptp(truth, axis=0)[moving]
    nrmse_gap = np.sqrt(np.mean(e_gap[:, moving] ** 2, axis=0)) / span
    nrmse_ref = np.sqrt(np.mean(e_ref[:, moving] ** 2, axis=0)) / span
    assert nrmse_gap.max() <= 1.5 * nrmse_ref.max(), (nrmse_gap.max(), nrmse_ref.max())
    known = np.isfinite(s_gap[:, moving])
    assert known.mean() > 0.9
    covered = np.abs(e_gap[:, moving]) <= 1.96 * s_gap[:, moving]
    assert covered[known].mean() >= 0.9, covered[known].mean()
