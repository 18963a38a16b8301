"""bag_viz on a recorded run (our writer, model torques at 1 kHz, a live body-size change in
the middle): the copy is read by rosbags (an independent reader, decoding MarkerArray from
the stored schema alone) and by ours; every input message is there unchanged; every
joint_torques has a MarkerArray within 1/rate before it; each array is the markers of the
model in force at its stamp."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from test_check_bag import T_START, Run, write_run
from visualization_msgs.msg import Marker, MarkerArray

from forearm_dynamics import build_model, get_movement
from forearm_dynamics.bag import BagWriter, open_bag
from forearm_dynamics.cli.bag_viz import main as bag_viz
from forearm_dynamics.model_config import model_config
from forearm_dynamics.viz import ArmScene, MarkerMaker, TorqueColours

pytestmark = pytest.mark.unit

MOVEMENTS = (28, 40)
RATE = 30.0


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("viz")
    src = d / "run.mcap"
    write_run(src, Run(movements=MOVEMENTS))
    # a live change: the torque node's config 2 (body size 95) applies from the second
    # movement on (the torques themselves stay the p50 ones: only the drawing is checked)
    switch = T_START + round(get_movement(MOVEMENTS[0]).duration * 1e9) + 100_000_000
    with_change = d / "change.mcap"
    bag = open_bag(src)
    with BagWriter(with_change) as w:
        ids = {}
        for ch in bag.info.channels.values():
            sid = w.add_schema(ch.schema_name, ch.schema_encoding, ch.schema_data)
            ids[ch.id] = w.add_channel(ch.topic, sid, ch.schema_name, ch.metadata)
        cfg = next(c for c in bag.info.channels.values() if c.topic.endswith("config"))
        done = False
        for ch, msg in bag.messages():
            if not done and msg.log_time > switch:
                text = json.dumps({**model_config(build_model("segmented", 95)), "config_id": 2,
                                   "applies_from_stamp_ns": switch})
                w.write(ids[cfg.id], serialize_message(String(data=text)), switch - 1000)
                done = True
            w.write(ids[ch.id], msg.data, msg.log_time, msg.publish_time)
    out = d / "viz.mcap"
    assert bag_viz([str(with_change), str(out)]) == 0
    return with_change, out, switch


def _by_topic(path):
    out: dict[str, list[tuple[int, bytes]]] = {}
    for ch, msg in open_bag(path).messages():
        out.setdefault(ch.topic, []).append((msg.log_time, bytes(msg.data)))
    return out


def test_every_input_message_is_copied_and_the_arm_is_added(bags):
    src, out, _ = bags
    before, after = _by_topic(src), _by_topic(out)
    assert set(after) == set(before) | {"/arm_markers", "/robot_description"}
    for topic, msgs in before.items():
        assert after[topic] == msgs, topic
    assert [deserialize_message(d, String).data for _, d in after["/robot_description"]] == \
        [build_model("segmented", 50).to_urdf(), build_model("segmented", 95).to_urdf()]


def test_rosbags_decodes_the_markers_from_the_stored_schema(bags):
    _, out, _ = bags
    ours = _by_topic(out)["/arm_markers"]
    with AnyReader([out]) as r:
        conns = [c for c in r.connections if c.topic == "/arm_markers"]
        assert [c.msgtype for c in conns] == ["visualization_msgs/msg/MarkerArray"]
        seen = [(t, r.deserialize(raw, c.msgtype)) for c, t, raw in r.messages(connections=conns)]
        desc = [c for c in r.connections if c.topic == "/robot_description"]
        assert desc[0].ext.offered_qos_profiles[0].durability.name == "TRANSIENT_LOCAL"
    assert [t for t, _ in seen] == [t for t, _ in ours]
    for (_, m), (_, data) in zip(seen, ours):
        ref = deserialize_message(data, MarkerArray)
        assert [x.ns for x in m.markers] == [x.ns for x in ref.markers]
        assert [x.pose.position.x for x in m.markers] == [x.pose.position.x for x in ref.markers]


def test_every_torque_has_markers_within_one_period_drawn_from_the_model_in_force(bags):
    _, out, switch = bags
    topics = _by_topic(out)
    torque_log = np.array([t for t, _ in topics["/joint_torques"]])
    marker_log = np.array([t for t, _ in topics["/arm_markers"]])
    k = np.searchsorted(marker_log, torque_log, side="right") - 1
    assert (k >= 0).all()
    assert (torque_log - marker_log[k] < 1e9 / RATE).all()
    duration = (torque_log[-1] - torque_log[0]) / 1e9
    assert abs(len(marker_log) - duration * RATE) <= 2 + 0.1 * duration * RATE
    torques = {}
    for _, d in topics["/joint_torques"]:
        m = deserialize_message(d, JointState)
        torques[m.header.stamp.sec * 10**9 + m.header.stamp.nanosec] = m
    makers = {p: MarkerMaker(ArmScene(a), TorqueColours(a.joint_names))
              for p, a in ((50, build_model("segmented", 50)), (95, build_model("segmented", 95)))}
    cleared = 0
    for _, data in topics["/arm_markers"]:
        arr = deserialize_message(data, MarkerArray)
        cleared += arr.markers[0].action == Marker.DELETEALL
        shapes = [x for x in arr.markers if x.action == Marker.ADD]
        stamp = shapes[0].header.stamp.sec * 10**9 + shapes[0].header.stamp.nanosec
        m = torques[stamp]
        maker = makers[95 if stamp >= switch else 50]
        want = maker.frame(np.array(m.position), np.array(m.effort))
        got = np.array([[x.pose.position.x, x.pose.position.y, x.pose.position.z] for x in shapes])
        np.testing.assert_allclose(got, want.positions, rtol=0, atol=1e-9)
        np.testing.assert_allclose([[x.scale.x, x.scale.y, x.scale.z] for x in shapes], want.scales,
                                   rtol=0, atol=1e-12)
    assert cleared == 2  # the first array, and the first after the change


def test_refusals_are_one_line_and_leave_nothing(bags, tmp_path, capsys):
    src, out, _ = bags
    before = out.stat().st_mtime_ns
    assert bag_viz([str(src), str(out)]) == 2
    err = capsys.readouterr().err
    assert "--overwrite" in err and len(err.strip().splitlines()) == 1
    assert out.stat().st_mtime_ns == before
    assert bag_viz([str(src), str(src), "--overwrite"]) == 2
    no_torques = tmp_path / "states.mcap"
    with BagWriter(no_torques) as w:
        ch = w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        w.write(ch, serialize_message(JointState()), 1)
    assert bag_viz([str(no_torques), str(tmp_path / "x.mcap")]) == 2
    assert "no joint_torques" in capsys.readouterr().err
    assert not (tmp_path / "x.mcap").exists() and not list(tmp_path.glob("*.part"))


def test_a_bag_torques_bag_is_drawn(tmp_path, capsys):
    from bagkit import write_stream_bag

    from forearm_dynamics.offline.torques import bag_torques

    states, torques = tmp_path / "states.mcap", tmp_path / "torques.mcap"
    write_stream_bag(states, 3000)
    bag_torques(states, torques, build_model("segmented", 50))
    assert bag_viz([str(torques), str(tmp_path / "viz.mcap")]) == 0
    assert "warning" not in capsys.readouterr().err
    assert len(_by_topic(tmp_path / "viz.mcap")["/arm_markers"]) >= 85  # 3 s at 30 Hz


def test_a_bag_without_indexes_is_copied_message_by_message(bags, tmp_path, capsys):
    """A recording cut before its summary (a recorder killed): no chunk index, so the
    general path; the same markers come out."""
    src, out, _ = bags
    data = src.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.98)])
    copy = tmp_path / "cut_viz.mcap"
    assert bag_viz([str(cut), str(copy)]) == 0
    assert "(by messages)" in capsys.readouterr().err
    whole, part = _by_topic(out)["/arm_markers"], _by_topic(copy)["/arm_markers"]
    assert 0 < len(part) <= len(whole) and part == whole[: len(part)]
