"""trajectory_publisher as a real process: every sample arrives, q and qd match the stamp
exactly, markers describe each movement, the process exits 0 (or 2 on bad parameters)."""

from __future__ import annotations

import json
import signal
import time

import numpy as np
import pytest
import rosproc
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics import JOINT_NAMES, get_movement
from forearm_dynamics.nodes.common import stream_qos
from forearm_dynamics.nodes.trajectory_publisher import marker_qos

RATE = 1000.0


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


@pytest.fixture
def peer():
    p = rosproc.Peer("trajectory_test")
    yield p
    p.close()


def listen(peer: rosproc.Peer) -> tuple[list[JointState], list[dict]]:
    samples: list[JointState] = []
    markers: list[dict] = []
    peer.node.create_subscription(JointState, "joint_states", samples.append, stream_qos(1000))
    peer.node.create_subscription(String, "movement", lambda m: markers.append(json.loads(m.data)),
                                  marker_qos())
    return samples, markers


def test_replays_movements_with_exact_stamps(peer) -> None:
    samples, markers = listen(peer)
    proc = rosproc.start("trajectory_publisher", "-p", "movements:=[1, 16]", "-p", "start_delay:=0.3",
                         "-p", "body_size:=95")
    try:
        assert peer.spin_until(lambda: not proc.running(), 30), proc.output()
        peer.spin_for(0.3)  # whatever is still in flight
    finally:
        rc = proc.stop(signal.SIGKILL)
    assert rc == 0, proc.output()
    assert "Traceback" not in proc.output()

    assert [m["id"] for m in markers] == [1, 16]
    for m in markers:
        mv = get_movement(m["id"])
        assert (m["name"], m["elbow"], m["body_size"]) == (mv.name, mv.elbow, 95)
        assert m["t0"] == pytest.approx(m["t0_ns"] / 1e9, abs=1e-6)

    stamps = np.array([stamp_ns(s) for s in samples])
    assert np.all(np.diff(stamps) > 0)
    t0s = [m["t0_ns"] for m in markers]
    assert stamps[0] == t0s[0] and t0s[1] in stamps  # each marker's t0 is a sample's stamp
    which = np.searchsorted(t0s, stamps, side="right") - 1
    for i, m in enumerate(markers):
        mv = get_movement(m["id"])
        mine = [s for s, w in zip(samples, which, strict=True) if w == i]
        assert abs(len(mine) - mv.duration * RATE) <= 1, (m, len(mine))
        t = (np.array([stamp_ns(s) for s in mine]) - m["t0_ns"]) / 1e9
        q, qd, _ = mv.evaluate(t)
        np.testing.assert_allclose([s.position for s in mine], q, rtol=0, atol=1e-12)
        np.testing.assert_allclose([s.velocity for s in mine], qd, rtol=0, atol=1e-12)
    assert all(list(s.name) == list(JOINT_NAMES) and len(s.effort) == 0 for s in samples)
    # evaluated at the stamp, published at ~1 kHz: spacing close to 1 ms, not exactly
    assert np.median(np.diff(stamps)) == pytest.approx(1e6, rel=0.05)


def test_loop_repeats_until_signalled(peer) -> None:
    _, markers = listen(peer)
    proc = rosproc.start("trajectory_publisher", "-p", "movements:=[3]", "-p", "loop:=true",
                         "-p", "start_delay:=0.2", "-p", "gap:=0.1", "-p", "rate_hz:=200")
    try:
        assert peer.spin_until(lambda: len(markers) >= 2, 20), proc.output()
        gap = (markers[1]["t0_ns"] - markers[0]["t0_ns"]) / 1e9
        assert gap == pytest.approx(get_movement(3).duration + 0.1, abs=0.02)
        assert [m["id"] for m in markers[:2]] == [3, 3]
    finally:
        rc = proc.stop(signal.SIGTERM)
    assert rc == 0, proc.output()


@pytest.mark.parametrize(("args", "name"), [
    (["movements:=[0, 5]"], "movements"),
    (["movements:=[66]"], "movements"),
    (["rate_hz:=0.0"], "rate_hz"),
    (["body_size:=42"], "body_size"),
    (["loop:=maybe"], "loop"),
])
def test_invalid_parameters_exit_2(args: list[str], name: str) -> None:
    ros_args = [x for a in args for x in ("-p", a)]
    proc = rosproc.start("trajectory_publisher", *ros_args)
    try:
        assert proc.wait(timeout=30) == 2, proc.output()
    finally:
        proc.stop(signal.SIGKILL)
    lines = [line for line in proc.output().splitlines() if line.strip()]
    assert len(lines) == 1 and f"invalid parameter '{name}'" in lines[0], lines


def test_waits_for_a_subscriber_then_gives_up(peer) -> None:
    """No joint_states subscriber: it waits subscriber_timeout, warns, replays, exits 0."""
    t = time.monotonic()
    proc = rosproc.start("trajectory_publisher", "-p", "movements:=[2]", "-p", "start_delay:=0.0",
                         "-p", "subscriber_timeout:=0.5", "-p", "output_topic:=nobody_listens")
    try:
        assert proc.wait(timeout=30) == 0, proc.output()
    finally:
        proc.stop(signal.SIGKILL)
    assert "0 of 1 subscribers" in proc.output()
    assert time.monotonic() - t >= 0.5 + get_movement(2).duration
