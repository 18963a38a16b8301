"""Live parameter changes of a running torque_node (real process, real DDS), during a 1 kHz
replay: every output sample is computed with the config in force at its stamp (read back
from the node's ~/config messages with the strict reader) to 1e-9 N·m at the exact state,
none is lost, and an invalid change is refused and changes nothing.

The input is a constant-acceleration trajectory with exact velocities, so the backward
estimator's acceleration is exact (a) once warm, and 0 on a warm-up sample (the first after
start and after an estimator change). The test prints what the switch costs (time from
the parameter request to the first output with the new model, the model build time, and
the output latency p99 around the switches against the steady state): numbers to report,
not pass/fail.
"""

from __future__ import annotations

import json
import re
import signal
import sys
import threading
import time

import numpy as np
import pytest
import rosproc
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from benchmarks.torque_node_rate import feed
from forearm_dynamics.model_config import config_in_force, model_from_config
from forearm_dynamics.nodes.common import stream_qos

pytestmark = pytest.mark.ros

MS = 1_000_000
N = 4000  # samples at 1 kHz
DEPTH = 10_000  # history of the input and output topics (messages)
RNG = np.random.default_rng(7)
Q0 = RNG.uniform(-0.3, 0.3, 20)
# a twentieth of the first draws: 4 s at +-2 rad/s^2 moved joints by up to 18 rad, far outside
# every range (refused as units since issue 30); this stays an arm's motion (|q| < 1.5 rad)
V0 = RNG.uniform(-0.5, 0.5, 20) / 5
ACC = RNG.uniform(-2.0, 2.0, 20) / 20

# (sample index at which to ask, parameters set together, expected to succeed)
CHANGES = [
    (700, {"body_size": 95}, True),
    # the left arm holding a 0.5 kg object (together: side alone gives the same torques,
    # by the sign conventions; the payload makes the switch visible)
    (1400, {"side": "left", "payload_mass": 0.5, "payload_com": [0.0, -0.06, -0.04]}, True),
    (2000, {"model": "anatomical", "body_size": 5}, True),  # atomically: one config
    (2500, {"body_size": 51}, False),  # not a body size: refused, nothing changes
    (3000, {"model": "solid", "estimator.accel_cutoff_hz": 50.0}, True),  # new estimator
]
#: config_id each accepted change produces (None: refused)
IDS = (2, 3, 4, None, 5)


def state(t_s: float) -> tuple[np.ndarray, np.ndarray]:
    return Q0 + V0 * t_s + 0.5 * ACC * t_s * t_s, V0 + ACC * t_s


def test_live_changes_during_a_1khz_replay() -> None:
    # The feeder thread shares this process with the spinning one: hand the GIL over
    # often, so a sample is published right after it is stamped (else the measured node
    # latency includes this process's thread switches).
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)
    try:
        _live_changes_during_a_1khz_replay()
    finally:
        sys.setswitchinterval(interval)


def _live_changes_during_a_1khz_replay() -> None:
    # the backward estimator: exact for this constant-acceleration stream after one sample,
    # so every output can be checked against the model in force to 1e-9
    # 10 s of history each way (the default 1 s rides out the node's own stalls): this process
    # both feeds at 1 kHz and receives, and on a loaded machine it stalled for longer than 1 s,
    # its reliable queues overflowed and the replies stopped at 3 749 of 4 000 (CI, 2026-12-06)
    proc = rosproc.start("torque_node", "-p", "diagnostics_period:=0.5", "-p", "estimator:=backward",
                         "-p", f"qos_depth:={DEPTH}")
    peer = rosproc.Peer("live_test")
    try:
        node = peer.node
        pub = node.create_publisher(JointState, "joint_states", stream_qos(DEPTH))
        outputs: list[tuple[int, JointState]] = []
        node.create_subscription(JointState, "joint_torques",
                                 lambda m: outputs.append((time.time_ns(), m)), stream_qos(DEPTH))
        configs: list[tuple[int, dict]] = []
        latched = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(String, "/torque_node/config",
                                 lambda m: configs.append((time.time_ns(), json.loads(m.data))), latched)
        client = node.create_client(SetParametersAtomically, "/torque_node/set_parameters_atomically")
        assert client.wait_for_service(timeout_sec=rosproc.STARTUP_S), proc.output()
        assert peer.spin_until(lambda: pub.get_subscription_count() > 0 and configs,
                               rosproc.STARTUP_S), proc.output()

        diags: list[tuple[int, dict]] = []  # the node's own latency per period
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: diags.extend(
            (time.time_ns(), {kv.key: kv.value for kv in st.values}) for st in m.status
            if st.name.startswith("torque_node")), 100)
        stamps: list[int] = []
        t0 = time.time_ns() + 200 * MS
        feeder = threading.Thread(target=feed, args=(pub, t0, MS, N, state, stamps), daemon=True)
        feeder.start()
        asked: list[tuple[int, dict, bool, object]] = []  # (wall ns, params, expected, future)
        for k, params, ok in CHANGES:
            assert peer.spin_until(lambda k=k: len(stamps) >= k, rosproc.STARTUP_S)
            req = SetParametersAtomically.Request(parameters=[
                Parameter(n, value=x).to_parameter_msg() for n, x in params.items()])
            asked.append((time.time_ns(), params, ok, client.call_async(req)))
        feeder.join(timeout=rosproc.STARTUP_S)
        assert len(stamps) == N
        assert peer.spin_until(lambda: len(outputs) >= N and all(f.done() for *_, f in asked),
                               rosproc.STARTUP_S), \
            (len(outputs), proc.output()[-3000:])
        peer.spin_for(0.6)  # the periodic config republication
        for _, params, ok, f in asked:
            r = f.result().result
            assert r.successful == ok, (params, r.reason)
            if not ok:
                assert "invalid parameter 'body_size'" in r.reason and "dict" not in r.reason, r.reason

        # none lost, none repeated, in order
        out_stamps = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for _, m in outputs]
        assert out_stamps == stamps

        applied = {}
        for _, c in configs:
            if c["applies_from_stamp_ns"] is not None:
                applied[c["config_id"]] = c
        assert sorted(applied) == [1, 2, 3, 4, 5], sorted(applied)  # the refused change made none
        models = {i: model_from_config(c).arm for i, c in applied.items()}
        first = {i: c["applies_from_stamp_ns"] for i, c in applied.items()}
        assert first[1] == 0 and stamps[0] < first[2] < first[3] < first[4] < first[5] <= stamps[-1]
        assert applied[5]["estimator"]["settings"]["accel_cutoff_hz"] == 50.0
        assert (applied[3]["side"], applied[3]["payload"]["mass"]) == ("left", 0.5)
        assert models[3].side == "left" and models[2].side == "right"
        assert (applied[4]["model"], applied[4]["body_size"]["label"]) == ("anatomical", "p5")

        worst = 0.0
        in_force = []
        warm: set[int] = set()  # outputs of a warm-up sample: computed with q̈ = 0
        for k, (_, m) in enumerate(outputs):
            t = out_stamps[k]
            cfg = config_in_force(configs, t)
            cid = cfg["config_id"]
            in_force.append(cid)
            q, qd = state((t - t0) * 1e-9)
            assert np.array_equal(np.asarray(m.position), q)
            err = float(np.abs(np.asarray(m.effort) - models[cid].inverse_dynamics(q, qd, ACC)).max())
            if err > 1e-9:  # the start, the new estimator's first sample, or after a stamp gap
                err = float(np.abs(np.asarray(m.effort) - models[cid].inverse_dynamics(
                    q, qd, np.zeros(20))).max())
                warm.add(t)
            worst = max(worst, err)
            assert err <= 1e-9, (k, cid, err)
        assert {out_stamps[0], first[5]} <= warm, sorted(warm)
        assert in_force == sorted(in_force)  # each config applies from its stamp on
        # the switch is visible: the old model does not fit the first sample of the new
        for cid in (2, 3, 4, 5):
            k = out_stamps.index(first[cid])
            q, qd = state((first[cid] - t0) * 1e-9)
            old = models[cid - 1].inverse_dynamics(q, qd, np.zeros(20) if first[cid] in warm else ACC)
            assert np.abs(np.asarray(outputs[k][1].effort) - old).max() > 1e-6

        # -- numbers (reported, not judged) -------------------------------------------
        # The node's own latency (receive - stamp, /diagnostics per 0.5 s period): periods
        # in which a switch happened against the others, during the replay.
        lines = []
        switch_walls = []
        for (wall, params, ok, _), cid in zip(asked, IDS, strict=True):
            if cid is None:
                continue
            switch_walls.append(first[cid])
            lines.append(f"  {params}: request -> first sample computed with config {cid} "
                         f"(its stamp): {(first[cid] - wall) / 1e6:.1f} ms; build "
                         f"{applied[cid]['build_ms']:.2f} ms")
        during, steady = [], []  # (latency p99 ms, callback p99 us, callback max us)
        for wall, d in diags:
            if int(d["processed_total"]) < 300 or d["latency_us_p99"] == "nan":
                continue
            row = (float(d["latency_us_p99"]) / 1e3, float(d["compute_us_p99"]),
                   float(d["compute_us_max"]))
            hit = any(wall - 600 * MS <= s <= wall for s in switch_walls)
            (during if hit else steady).append(row)
        steady_a = np.array(steady)
        print(f"\nlive changes during a 1 kHz replay ({N} samples, worst |error| {worst:.2e} N·m):")
        print("\n".join(lines))
        print(f"  per 0.5 s period, steady (median of {len(steady)}): latency p99 "
              f"{np.median(steady_a[:, 0]):.3f} ms, callback p99/max {np.median(steady_a[:, 1]):.0f}/"
              f"{np.median(steady_a[:, 2]):.0f} us; periods with a switch: "
              + ", ".join(f"{a:.3f} ms, {b:.0f}/{c:.0f} us" for a, b, c in during))
        node.destroy_client(client)
    finally:
        peer.close()
        code = proc.stop(signal.SIGINT)
        out = proc.output()
    assert code == 0 and "Traceback" not in out, out[-3000:]
    # warm-up: the start and the new estimator; beyond those, only the samples after a
    # stamp gap (this process's feeder stalled > 0.1 s on a loaded machine), as many as
    # the node counted, each one seen above as an output with q̈ = 0
    summary = re.search(r"summary: received (\d+), processed (\d+) \(warm-up (\d+)\), rejected 0"
                        r"(?:; estimator resets: stamp_gap (\d+))?", out, re.MULTILINE)
    assert summary, out[-2000:]
    received, processed, warmup, gaps = (int(x or 0) for x in summary.groups())
    assert received == processed == N and warmup == 2 + gaps == len(warm), (summary[0], sorted(warm))
