"""muscle_node's per-sample encoding (nodes/muscle_io.py), against independent readers.

- input: a joint_torques message (names in any order, a frame_id) read by StateReader gives
  exactly the numbers rclpy's deserialiser reads, in model joint order; a message without
  efforts or velocities is refused with its reason;
- output: the muscle_forces and muscle_reserves bytes the node publishes, written into the
  templates as the node writes them, equal byte for byte what rosbags' serialiser makes of the
  same JointState (its own CDR code: header, names, arrays, zero padding, size), and decode with
  rclpy's deserialiser to the message built the slow way (message object, exact equality).
"""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState
from support.jointstate import joint_state, joint_state_bytes

from forearm_dynamics.description import JOINT_NAMES
from forearm_dynamics.muscles import load_muscle_model
from forearm_dynamics.nodes import validation as v
from forearm_dynamics.nodes.input_plans import InputPlans
from forearm_dynamics.nodes.muscle_io import NO_EFFORT, NO_VELOCITY, OutputTemplates, StateReader

pytestmark = pytest.mark.unit

TS = get_typestore(Stores.ROS2_JAZZY)
JS = TS.types["sensor_msgs/msg/JointState"]
HDR, TIME = TS.types["std_msgs/msg/Header"], TS.types["builtin_interfaces/msg/Time"]


def _plan_and_read(data: bytes, reader: StateReader):
    plan = InputPlans(v.NameMatcher(JOINT_NAMES)).find(data)
    assert plan.layout is not None and plan.rejection is None
    plan.buf[:] = data
    reader.read(plan)
    return plan


def test_state_reader_reads_what_rclpy_reads_in_model_order():
    rng = np.random.default_rng(3)
    order = rng.permutation(len(JOINT_NAMES))
    names = [JOINT_NAMES[i] for i in order]
    q, qd, tau = rng.normal(size=(3, len(names)))
    data = joint_state_bytes(1_700_000_000_123_456_789, q, qd, tau, names=names, frame_id="arm")
    reader = StateReader("joint_torques", len(JOINT_NAMES))
    _plan_and_read(data, reader)
    msg = deserialize_message(data, JointState)
    back = np.argsort(order)  # model joint j sits at message slot back[j]
    for row, field in zip(reader.state, (msg.position, msg.velocity, msg.effort), strict=True):
        assert np.array_equal(row, np.asarray(field)[back])  # exact: the same doubles
    # a second message of the same shape: the cached reader, new numbers
    data2 = joint_state_bytes(1_700_000_000_223_456_789, -q, -qd, -tau, names=names, frame_id="arm")
    _plan_and_read(data2, reader)
    assert np.array_equal(reader.state, -np.stack([q, qd, tau])[:, back])


@pytest.mark.parametrize("velocity, effort, reason", [(True, False, NO_EFFORT),
                                                      (False, True, NO_VELOCITY)])
def test_state_reader_refuses_a_message_without_efforts_or_velocities(velocity, effort, reason):
    n = len(JOINT_NAMES)
    data = joint_state_bytes(1, np.zeros(n), np.zeros(n) if velocity else None,
                             np.zeros(n) if effort else None)
    reader = StateReader("joint_torques", n)
    with pytest.raises(v.Rejection) as exc:
        _plan_and_read(data, reader)
    assert exc.value.reason == reason and "joint_torques" in str(exc.value)


@pytest.mark.parametrize("frame_id", ["", "arm", "a_longer_frame_id/with/slashes"])
def test_outputs_equal_rosbags_bytes_and_rclpy_reads_the_slow_path_message(frame_id):
    mm = load_muscle_model()
    rng = np.random.default_rng(len(frame_id))
    a, speed, force = rng.uniform(0, 1, mm.n), rng.normal(size=mm.n), rng.uniform(0, 900, mm.n)
    reserves = rng.normal(size=len(JOINT_NAMES))
    sec, nsec = 1_700_000_123, 987_654_321
    outs = OutputTemplates(mm.names, JOINT_NAMES)
    out, res = outs.get(frame_id.encode())
    for _ in range(2):  # a template reused: the second sample's bytes hold only its numbers
        np.copyto(out.q, a)  # as MuscleNode._on_torques writes them
        np.copyto(out.effort, force)
        np.copyto(out.qd, speed)
        out.pack_stamp(sec, nsec)
        forces_bytes, reserves_bytes = out.payload(), res.fill(sec, nsec, reserves)
    stamp_ns = sec * 10**9 + nsec
    hdr = HDR(stamp=TIME(sec=sec, nanosec=nsec), frame_id=frame_id)
    # byte for byte: rosbags' serialiser of the same message
    assert forces_bytes == bytes(TS.serialize_cdr(
        JS(header=hdr, name=list(mm.names), position=a, velocity=speed, effort=force),
        JS.__msgtype__))
    assert reserves_bytes == bytes(TS.serialize_cdr(
        JS(header=hdr, name=list(JOINT_NAMES), position=np.zeros(0), velocity=np.zeros(0),
           effort=reserves), JS.__msgtype__))
    # the slow path: a message object, exact equality after rclpy's deserialiser
    assert deserialize_message(forces_bytes, JointState) == joint_state(
        stamp_ns, a, speed, force, names=mm.names, frame_id=frame_id)
    assert deserialize_message(reserves_bytes, JointState) == joint_state(
        stamp_ns, None, None, reserves, frame_id=frame_id)


def test_output_templates_follow_a_rebuilt_models_names():
    mm = load_muscle_model()
    outs = OutputTemplates(mm.names, JOINT_NAMES)
    before = outs.get(b"arm")
    outs.rename(mm.names)  # same muscles: templates kept
    assert outs.get(b"arm") is before
    outs.rename(mm.names[::-1])
    out, _ = outs.get(b"arm")
    assert out is not before[0] and out.layout.names == tuple(mm.names[::-1])
