"""End to end: torque_node + bag_recorder + trajectory_publisher as real processes, then the
bag checked by check_bag and read back by an independent reader (rosbags)."""

import json
import subprocess
import sys

import numpy as np
import pytest
import yaml
from rosproc import BIN, ros_env, start

from forearm_dynamics import JOINT_NAMES, build_model, get_movement
from forearm_dynamics.paths import config_file

MOVEMENTS = [3, 9, 19, 30, 55]  # elbow 90, 0 (supination), flexing, extending, full pronation


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("pipeline")
    bag = out / "run.mcap"
    node = start("torque_node")
    rec = start("bag_recorder", "-p", f"output:={bag}")
    pub = None
    try:
        assert node.wait_for_output("config on", 20), node.output()
        pub = start("trajectory_publisher", "-p", f"movements:={MOVEMENTS}", "-p", "start_delay:=2.0",
                    "-p", "min_subscribers:=2", "-p", "subscriber_timeout:=30.0")
        assert pub.wait(timeout=90) == 0, pub.output()
    finally:
        if pub is not None and pub.running():
            pub.stop()
        rec_code = rec.stop()
        node_code = node.stop()
    assert rec_code == 0, rec.output()
    assert node_code == 0, node.output()
    # Latency is a benchmark figure (make bench), not a pass/fail on a shared machine:
    # the test's thresholds keep everything but the latency gate.
    th = yaml.safe_load(config_file("check.yaml").read_text())
    th["latency_p99_ms_max"] = 1e6
    th_path = out / "check.yaml"
    th_path.write_text(yaml.safe_dump(th))
    report = out / "report.json"
    chk = subprocess.run([str(BIN / "check_bag"), str(bag), "--json", str(report), "--thresholds",
                          str(th_path)], env=ros_env(), capture_output=True, text=True, timeout=120,
                         check=False)
    return bag, chk, json.loads(report.read_text())


def test_check_bag_passes(run):
    _, chk, report = run
    assert chk.returncode == 0, chk.stdout + chk.stderr
    assert sorted(m["id"] for m in report["movements"]) == MOVEMENTS


def test_rosbags_reads_every_pair(run):
    """Independent reader: topics, types, and every joint_states answered by joint_torques."""
    from rosbags.highlevel import AnyReader

    bag, _, _ = run
    with AnyReader([bag]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/joint_states"] == "sensor_msgs/msg/JointState"
        assert types["/joint_torques"] == "sensor_msgs/msg/JointState"
        assert types["/movement"] == "std_msgs/msg/String"
        assert types["/torque_node/config"] == "std_msgs/msg/String"
        assert types["/diagnostics"] == "diagnostic_msgs/msg/DiagnosticArray"
        stamps = {"/joint_states": [], "/joint_torques": []}
        torques = {}
        markers = []
        for conn, _t, raw in reader.messages():
            if conn.topic in stamps:
                # rosbags reads the header alone: a JointState with an empty effort sequence,
                # as Fast-CDR pads it, trips its full decoder (see README, "Bags").
                sec, nsec = np.frombuffer(raw[4:12], dtype="<u4")
                stamp = int(sec) * 10**9 + int(nsec)
                stamps[conn.topic].append(stamp)
                if conn.topic == "/joint_torques":
                    msg = reader.deserialize(raw, conn.msgtype)
                    assert list(msg.name) == list(JOINT_NAMES)
                    torques[stamp] = (np.asarray(msg.position), np.asarray(msg.velocity),
                                      np.asarray(msg.effort))
            elif conn.topic == "/movement":
                markers.append(json.loads(reader.deserialize(raw, conn.msgtype).data))
    n_expected = sum(round(get_movement(m).duration * 1000) for m in MOVEMENTS)
    assert len(stamps["/joint_states"]) == n_expected
    assert set(stamps["/joint_states"]) == set(stamps["/joint_torques"])
    assert [m["id"] for m in markers] == MOVEMENTS
    # torques answer the state they carry (qdd estimated by the node: compare a still sample)
    model = build_model("segmented")
    first = markers[0]
    q, qd, _ = get_movement(first["id"]).evaluate([0.1])
    stamp = min(s for s in torques if s >= first["t0_ns"] + 100_000_000)
    pos, vel, eff = torques[stamp]
    np.testing.assert_allclose(pos, q[0], atol=1e-12)
    np.testing.assert_allclose(vel, qd[0], atol=1e-12)
    np.testing.assert_allclose(eff, model.gravity_torques(pos), atol=1e-9)


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
