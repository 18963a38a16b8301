"""A live stream in the wrong units against a real torque_node process over loopback DDS.

Issue 30: a stream of degrees (a sensor driver that forgot to convert) gave torques of
hundreds of N·m with no word. Now: the node's first line about the stream says units, no
torque is published from those samples, /diagnostics counts them (ERROR), and the node keeps
running: the same movement in radians is answered at once.
"""

from __future__ import annotations

import math
import signal
import time

import numpy as np
import pytest
import rosproc
from faultkit import private_domain
from sensor_msgs.msg import JointState
from support.jointstate import joint_state
from support.torque_harness import Diagnostics

from forearm_dynamics import movement_library
from forearm_dynamics.nodes.common import stream_qos

pytestmark = [pytest.mark.ros, pytest.mark.faults]

MS = 1_000_000


def test_live_stream_of_degrees_is_refused_naming_units(procs):
    domain = private_domain()
    proc = procs.start("torque_node", "-p", "diagnostics_period:=0.2", domain=domain)
    peer = rosproc.Peer("units_live_test", domain=domain)
    try:
        node = peer.node
        pub = node.create_publisher(JointState, "joint_states", stream_qos(1000))
        replies: list[JointState] = []
        node.create_subscription(JointState, "joint_torques", replies.append, stream_qos(1000))
        diag = Diagnostics(peer, "torque_node")
        assert peer.spin_until(lambda: pub.get_subscription_count() > 0, rosproc.STARTUP_S), proc.output()
        assert peer.spin_until(lambda: node.count_subscribers("joint_torques") >= 1
                               and node.count_publishers("joint_torques") >= 1, rosproc.STARTUP_S)
        # the node's start-up lines end with the model's ("... config on /torque_node/config");
        # its subscription may match before it is logged: wait for it (a hang guard)
        assert proc.wait_for_output("config on", rosproc.STARTUP_S), proc.output()
        # and the node has matched this peer on both topics (it logs each side): nothing
        # else is said once the stream starts
        for line in ("/joint_torques: matched by 1", "/joint_states: receiving from 1"):
            assert proc.wait_for_output(line, rosproc.STARTUP_S), \
                f"{proc.output()}\n{peer.endpoints('/joint_torques')}\n{peer.endpoints('/joint_states')}"
        mark = len(proc.output())
        mv = movement_library()[0]
        t = mv.sample_times(1000.0)[:300]
        q, qd, _ = mv.evaluate(t)
        t0 = time.time_ns()
        for k in range(len(t)):  # degrees, as a driver that forgot to convert sends them
            pub.publish(joint_state(t0 + k * MS, np.degrees(q[k]), np.degrees(qd[k])))
        deadline = time.monotonic() + 60  # a hang guard
        while "angle_out_of_range" not in proc.output()[mark:]:
            assert time.monotonic() < deadline and proc.running(), proc.output()[-3000:]
            peer.spin_for(0.1)
        said = [ln for ln in proc.output()[mark:].splitlines() if ln.strip()]
        assert "check units" in said[0] and "far outside" in said[0] and "deg" in said[0], said[:3]
        d = diag.fresh(lambda v: int(v.get("rejected.angle_out_of_range", 0)) >= 1)
        assert int(d["angles_far_out_of_range"]) >= 1
        peer.spin_for(0.5)
        assert replies == [], "a torque was published from angles in degrees"
        # the node keeps running: the same movement in radians is answered
        t1 = time.time_ns()
        for k in range(50):
            pub.publish(joint_state(t1 + k * MS, q[k], qd[k]))
        assert peer.spin_until(lambda: len(replies) >= 50, 60), proc.output()[-3000:]
        assert all(math.isfinite(x) for r in replies for x in r.effort)
        assert max(abs(x) for r in replies for x in r.effort) < 50  # N·m: a real arm's
    finally:
        peer.close()
    assert proc.stop(signal.SIGINT) == 0, proc.output()[-3000:]
    assert "Traceback" not in proc.output()
