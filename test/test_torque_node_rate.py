"""output_rate_hz end to end (real processes): a 100 Hz input (positions + exact velocities
of a constant-acceleration trajectory) into torque_node with output_rate_hz 1000 gives a
~1 kHz output, every message stamped with its own publication time and computed from the
estimator's prediction to that time (exact here: the prediction of a constant acceleration
is exact, so each output is the model's torque at the true state of its stamp), no
repeated stamp or value, and nothing once the input has stopped for input_timeout, said
in /diagnostics. The publish intervals (p50/p99) are printed: numbers, not pass/fail.
"""

from __future__ import annotations

import signal
import time

import numpy as np
import rosproc
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.nodes.common import stream_qos

MS = 1_000_000
RNG = np.random.default_rng(11)
Q0 = RNG.uniform(-0.3, 0.3, 20)
V0 = RNG.uniform(-0.5, 0.5, 20)
ACC = RNG.uniform(-2.0, 2.0, 20)
INPUTS = 200  # 2 s at 100 Hz
MODEL = build_model("segmented", 50)


def state(t_s: float):
    return Q0 + V0 * t_s + 0.5 * ACC * t_s * t_s, V0 + ACC * t_s


def test_fixed_output_rate_from_a_100hz_input() -> None:
    proc = rosproc.start("torque_node", "-p", "output_rate_hz:=1000.0", "-p", "input_timeout:=0.2",
                         "-p", "diagnostics_period:=0.25")
    peer = rosproc.Peer("rate_test")
    try:
        node = peer.node
        pub = node.create_publisher(JointState, "joint_states", stream_qos(1000))
        outs: list[JointState] = []
        node.create_subscription(JointState, "joint_torques", outs.append, stream_qos(10000))
        diags: list[dict] = []
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: diags.extend(
            {kv.key: kv.value for kv in st.values} | {"_message": st.message} for st in m.status
            if st.name.startswith("torque_node")), 100)
        assert peer.spin_until(lambda: pub.get_subscription_count() > 0, 20), proc.output()
        peer.spin_for(0.5)
        assert not outs  # no input yet: nothing published
        msg = JointState()
        msg.name = list(JOINT_NAMES)
        t0 = time.time_ns()
        in_stamps = []
        for k in range(INPUTS):
            due = t0 + k * 10 * MS
            while time.time_ns() < due:
                peer.executor.spin_once(timeout_sec=max(0.0, min(0.002, (due - time.time_ns()) / 1e9)))
            t = time.time_ns()
            q, qd = state((t - t0) * 1e-9)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)
            msg.position, msg.velocity = q.tolist(), qd.tolist()
            pub.publish(msg)
            in_stamps.append(t)
        n_at_stop = len(outs)
        peer.spin_for(1.5)  # input stopped: at most input_timeout more, then silence
        n_after = len(outs)
        peer.spin_for(1.0)
        assert len(outs) == n_after, "still publishing 1.5 s after the input stopped"
        assert any(d["_message"] == "not publishing: input timeout" and
                   int(d["timer_skipped.input_timeout"]) > 0 for d in diags), diags[-1:]

        stamps = np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in outs])
        assert (np.diff(stamps) > 0).all()  # no repeated stamp
        effort = np.array([m.effort for m in outs])
        assert (np.abs(np.diff(effort, axis=0)).max(axis=1) > 0).all()  # no repeated value
        assert stamps[0] >= in_stamps[0] and stamps[-1] <= in_stamps[-1] + 2_000 * MS
        # every output after the estimator is warm (second input) is exact at its stamp
        warm = stamps > in_stamps[1] + 5 * MS  # received by then, whatever the machine load
        assert warm.sum() > 0.5 * len(outs)
        worst = 0.0
        for m, t in zip(np.array(outs, dtype=object)[warm], stamps[warm], strict=True):
            q, qd = state((t - t0) * 1e-9)
            np.testing.assert_allclose(m.position, q, rtol=0, atol=1e-9)
            err = np.abs(np.asarray(m.effort) - MODEL.inverse_dynamics(q, qd, ACC)).max()
            worst = max(worst, err)
        assert worst < 1e-9, worst
        # upsampled: many more outputs than inputs (1000 Hz nominal from 100 Hz)
        assert len(outs) > 3 * INPUTS, len(outs)
        span = (in_stamps[-1] - in_stamps[0]) / 1e9
        steady = stamps[(stamps > in_stamps[0] + 200 * MS) & (stamps < in_stamps[-1])]
        iv = np.diff(steady) / 1e6
        print(f"\noutput_rate_hz 1000 from 100 Hz: {n_at_stop} outputs while {INPUTS} inputs came "
              f"in {span:.2f} s ({len(steady) / ((steady[-1] - steady[0]) / 1e9):.1f} Hz steady); "
              f"publish interval p50/p99/max {np.percentile(iv, 50):.3f}/{np.percentile(iv, 99):.3f}/"
              f"{iv.max():.3f} ms; {len(outs) - n_at_stop} after the last input; worst |error| at "
              f"the exact state {worst:.1e} N·m")
    finally:
        peer.close()
        code = proc.stop(signal.SIGINT)
    out = proc.output()
    assert code == 0 and "Traceback" not in out, out[-3000:]
    assert "no input for" in out and "timer outputs skipped" in out
