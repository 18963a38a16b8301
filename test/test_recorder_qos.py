"""bag_recorder adapts each stream subscription to the QoS its publishers offer (as
`ros2 bag record` does): a best-effort joint_states publisher is recorded, where a reliable
reader would match nothing ("offering incompatible QoS"). Real processes on loopback."""

from __future__ import annotations

import pytest
import rosproc

from forearm_dynamics.bag import open_bag
from forearm_dynamics.processes import Child

pytestmark = pytest.mark.ros


def test_best_effort_publisher_is_recorded_best_effort(tmp_path):
    domain = rosproc.test_domain(140, 229)
    bag = tmp_path / "be.mcap"
    rec = rosproc.start("bag_recorder", "-p", f"output:={bag}", "-p", "topics:=[joint_states]",
                        domain=domain)
    pub: Child | None = None
    try:
        pub = rosproc.start("trajectory_publisher", "-p", "movements:=[1]", "-p", "qos_reliable:=false",
                            "-p", "start_delay:=1.0", "-p", "subscriber_timeout:=60.0", "-p", "drain:=1.0",
                            domain=domain)
        assert pub.wait(timeout=120) == 0, pub.output()
        code = rec.stop()
        assert code == 0, rec.output()
    finally:
        for p in (pub, rec):
            if p is not None and p.running():
                p.stop()
    assert "joint_states: subscribed best effort" in rec.output(), rec.output()
    n = sum(1 for _ch, _m in open_bag(bag).messages(["/joint_states"]))
    assert n > 0, rec.output()  # a reliable subscription would have matched nothing: 0
