"""Samples lost in bursts (a starved node's best-effort input) are not noise.

Stop 39's two-host run beside a second `make test` (load 9): the torque node, 1 s behind,
answered 12 795 of 15 000 samples (598 of movement 8's 1 500), what its best-effort reader
kept. test/data/two_host_starved_input.npz holds those samples' stamps (the publisher's:
jittered, its own stalls' bursts) and the movements' start stamps; the positions and
velocities are the library movements' at those stamps, exactly what the publisher sent (checked
against the run's bag: equal to 0.0). Replayed through the node's estimator (its update()
calls), the noise estimate read the holes as 0.11 rad of pro/sup noise, the filter (given
velocities) then ignored positions, and movement 10's real 0.63 rad step from movement 9's
end went uncorrected for a second: the node's torques, to 0.0 N·m, with pipeline NRMSE
30.6 % (check_bag: > 2 %). estimation/noise.py now skips windows whose blocks do not compare
(WINDOW_STRETCH, BLOCK_SPREAD_RATIO): 39 of 625 here; the belief then peaks at 0.045 rad
(elbow, in movement 9: 762 of 1 500 samples came), not 0.19, and every movement's torques are
within 0.56 % (measured). What is required is the user's: every movement within check_bag's
2 % per DOF."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from forearm_dynamics import build_model, get_movement
from forearm_dynamics.estimation import make_estimator

pytestmark = pytest.mark.unit

DATA = Path(__file__).resolve().parent / "data" / "two_host_starved_input.npz"
T0 = 1_796_570_090_802_193_644  # the run's first stamp


def _input():
    """(stamps ns, q, qd, movement id, time in the movement) of the samples the node got."""
    d = np.load(DATA)
    stamps = T0 + d["stamp_offset_ns"]
    t0s, ids = T0 + d["marker_offset_ns"], d["marker_id"]
    k = np.searchsorted(t0s, stamps, side="right") - 1
    assert (k >= 0).all()
    q, qd = np.empty((len(stamps), 20)), np.empty((len(stamps), 20))
    tm = np.empty(len(stamps))
    for j, (t0, mid) in enumerate(zip(t0s, ids)):
        sel = k == j
        mv = get_movement(int(mid))
        tm[sel] = np.minimum((stamps[sel] - t0) / 1e9, mv.duration)
        q[sel], qd[sel], _ = mv.evaluate(tm[sel])
    return stamps, q, qd, ids[k], tm


def test_bursty_loss_is_not_read_as_noise_and_a_later_step_is_followed() -> None:
    stamps, q, qd, mids, tm = _input()
    assert len(stamps) == 12_795 and (mids == 8).sum() == 598  # the run's input
    est = make_estimator("kalman", 20)
    eq, eqd, eqdd, _ = est.run(stamps, q, qd)  # the node's update() calls
    ne = est.noise_estimator
    assert ne.irregular_windows > 0  # the guard skipped the starved stretch's windows
    arm = build_model("segmented")
    worst = {}
    for mid in np.unique(mids):  # every movement's torques within check_bag's 2 % per DOF
        sel = mids == mid
        mv = get_movement(int(mid))
        exact = arm.inverse_dynamics(*mv.evaluate(tm[sel]))
        got = arm.inverse_dynamics_batch(eq[sel], eqd[sel], eqdd[sel])
        ptp = np.ptp(arm.inverse_dynamics(*mv.evaluate(mv.sample_times(1000.0))), axis=0)
        scored = ptp > 0.02 * ptp.max()
        worst[int(mid)] = float((np.sqrt(np.mean((got - exact) ** 2, axis=0))[scored]
                                 / ptp[scored]).max())
    assert max(worst.values()) < 0.02, worst
