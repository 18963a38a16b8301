"""A bag with joint_torques_std: bag_torques writes it (read back with rosbags: one σ message
per torque message, same header and names, the offline API's numbers), bag_export adds the
σ columns, check_bag scores the calibration against the exact-state truth (reported; gated
only with --std-coverage / --std-ratio). The replay through bag_player: test_torque_std_node.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosproc import BIN, ros_env
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics import JOINT_NAMES, build_model, get_movement
from forearm_dynamics.bag import BagWriter
from forearm_dynamics.bag.rosbag2_meta import TopicQos
from forearm_dynamics.uncertainty import inverse_dynamics_with_std

pytestmark = pytest.mark.cli

T_START = 1_750_000_000_000_000_000
MOVEMENTS = (4, 19)  # pronation and wrist extension, each with the elbow flexing
RATE = 100.0
NOISE_DEG = 0.5
LEAD = 50  # samples of held start posture before each movement's marker (not scored)


def run(tool: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / tool), *map(str, args)], env=ros_env(), capture_output=True,
                          text=True, timeout=300, check=False)


def write_input(path: Path) -> dict:
    """joint_states (positions only, 0.5 deg noise, 100 Hz) with movement markers, as
    trajectory_publisher with noise_deg 0.5 publishes them; the exact states returned."""
    stamps, zs = [], []
    rng = np.random.default_rng(23)
    period = round(1e9 / RATE)
    with BagWriter(path, flush_period_s=3600) as w:
        js = w.add_topic("/joint_states", "sensor_msgs/msg/JointState", TopicQos(depth=1000))
        mv_ch = w.add_topic("/movement", "std_msgs/msg/String")
        t0 = T_START
        for mid in MOVEMENTS:
            mv = get_movement(mid)
            t = np.concatenate([np.arange(-LEAD, 0) / RATE, mv.sample_times(RATE)])
            q, _qd, _qdd = mv.evaluate(t)
            z = q + rng.normal(0.0, math.radians(NOISE_DEG), q.shape)
            marker = {"id": mid, "name": mv.name, "elbow": mv.elbow, "body_size": 50, "t0_ns": t0,
                      "sensor": {"noise_deg": NOISE_DEG, "publish_velocity": False}}
            w.write(mv_ch, serialize_message(String(data=json.dumps(marker))), t0 - LEAD * period - 1000)
            for k in range(len(t)):
                stamp = t0 + round(t[k] * 1e9)
                m = JointState(name=list(JOINT_NAMES), position=z[k].tolist())
                m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp, 10**9)
                m.header.frame_id = "humerus"
                w.write(js, serialize_message(m), stamp + 50_000)
                stamps.append(stamp)
                zs.append(z[k])
            # the next lead starts after this movement's check_bag window (duration + 0.5 s)
            t0 += round(mv.duration * 1e9) + (LEAD + 80) * period
    return {"stamps": np.array(stamps, np.int64), "z": np.array(zs)}


def read(path: Path) -> dict:
    out: dict = {"torques": {}, "std": {}, "config": None, "topics": {}}
    with AnyReader([path]) as r:
        for c, _t, raw in r.messages():
            out["topics"][c.topic] = out["topics"].get(c.topic, 0) + 1
            if c.topic in ("/joint_torques", "/joint_torques_std"):
                m = r.deserialize(raw, c.msgtype)
                key = "torques" if c.topic == "/joint_torques" else "std"
                out[key][m.header.stamp.sec * 10**9 + m.header.stamp.nanosec] = m
            elif c.topic == "/torque_node/config":
                out["config"] = json.loads(r.deserialize(raw, c.msgtype).data)
    return out


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("stdbag")
    src, out = d / "in.mcap", d / "out.mcap"
    written = write_input(src)
    r = run("bag_torques", src, out)
    assert r.returncode == 0, r.stderr
    assert "joint_torques_std: 1σ per torque" in r.stdout, r.stdout
    return src, out, written


def test_bag_torques_writes_one_sigma_per_torque_with_the_same_header(bags) -> None:
    _src, out, written = bags
    got = read(out)
    n = len(written["stamps"])
    assert got["topics"]["/joint_torques"] == got["topics"]["/joint_torques_std"] == n
    for s in written["stamps"][::41]:
        tq, sd = got["torques"][int(s)], got["std"][int(s)]
        assert sd.header.frame_id == tq.header.frame_id == "humerus"
        assert (sd.header.stamp.sec, sd.header.stamp.nanosec) == \
            (tq.header.stamp.sec, tq.header.stamp.nanosec)
        assert list(sd.name) == list(tq.name) == list(JOINT_NAMES)
        assert len(sd.position) == 0 and len(sd.velocity) == 0
    cfg = got["config"]["std"]
    assert cfg["published"] is True and cfg["topic"].endswith("joint_torques_std")
    assert "results/paper/results.json" in cfg["model"]


def test_bag_sigma_is_the_offline_apis(bags) -> None:
    """The API on the same samples (the stamp gap between the movements resets both)."""
    _src, out, written = bags
    got = read(out)
    stamps, z = written["stamps"], written["z"]
    api = inverse_dynamics_with_std(build_model(), stamps, z, t_in_ns=True)
    sd = np.array([got["std"][int(s)].effort for s in stamps])
    tq = np.array([got["torques"][int(s)].effort for s in stamps])
    np.testing.assert_allclose(tq, api.tau, rtol=0, atol=1e-9)
    assert np.array_equal(np.isinf(sd).all(axis=1), ~api.known) and (~api.known).sum() >= 2  # 2 starts
    np.testing.assert_allclose(sd[api.known], api.std[api.known], rtol=1e-12)


def test_bag_export_adds_the_sigma_columns(bags, tmp_path) -> None:
    _src, out, written = bags
    csv_path = tmp_path / "t.csv"
    r = run("bag_export", out, "--format", "csv", "--out", csv_path)
    assert r.returncode == 0, r.stderr
    with open(csv_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(written["stamps"])
    got = read(out)
    warming = 0
    for row in rows:
        sd = got["std"][int(row["stamp_ns"])].effort
        warming += bool(np.isinf(sd).any())
        for j, name in enumerate(JOINT_NAMES):  # never inf: an unknown σ is an empty cell
            cell = row[f"{name}_moment_std"]
            assert cell == "" if np.isinf(sd[j]) else float(cell) == sd[j], (cell, sd[j])
    assert warming >= 2 and f"{warming} rows without a known σ (empty cells" in r.stdout, r.stdout
    r = run("bag_export", out, "--format", "csv", "--out", tmp_path / "n.csv", "--no-std")
    assert r.returncode == 0 and "_moment_std" not in (tmp_path / "n.csv").read_text().splitlines()[0]


def test_check_bag_scores_the_calibration_and_gates_only_when_asked(bags, tmp_path) -> None:
    _src, out, _ = bags
    js = tmp_path / "r.json"
    r = run("check_bag", out, "--json", js)
    assert "torque σ (joint_torques_std) vs the exact-state truth" in r.stdout, r.stdout
    cal = json.loads(js.read_text())["std_calibration"]
    assert set(cal["groups"]) == {"pro_sup", "elbow", "wrist", "thumb", "fingers"}
    assert cal["unmatched"] == 0 and cal["samples"] > 200
    for g, v in cal["groups"].items():  # the benchmark's targets hold on this bag too
        assert 0.90 <= v["coverage"] <= 0.985 and 0.8 <= v["ratio"] <= 1.5, (g, v)
    code = r.returncode
    ok = run("check_bag", out, "--std-coverage", "0.90,0.985", "--std-ratio", "0.8,1.5")
    assert ok.returncode == code, ok.stdout  # within the asked ranges: the verdict is unchanged
    bad = run("check_bag", out, "--std-coverage", "0.99,1.0")
    assert bad.returncode == 1 and "FAIL: std calibration: " in bad.stdout, bad.stdout
    usage = run("check_bag", out, "--std-ratio", "2,1")
    assert usage.returncode == 2 and "Traceback" not in usage.stderr


def test_check_bag_asked_to_gate_a_bag_without_sigma_fails(bags, tmp_path) -> None:
    src, _out, _ = bags
    plain = tmp_path / "plain.mcap"
    assert run("bag_torques", src, plain, "--no-std").returncode == 0
    r = run("check_bag", plain, "--std-coverage", "0.9,0.98")
    assert r.returncode == 1 and "no joint_torques_std" in r.stdout, r.stdout


def test_bag_torques_subject_std_adds_the_part(bags, tmp_path) -> None:
    """--subject-std ansur: the σ is the API's with subject="ansur" (wider than without on
    every sample whose σ is known) and the bag's config states ANSUR II."""
    src, _out, written = bags
    out = tmp_path / "subject.mcap"
    r = run("bag_torques", src, out, "--subject-std", "ansur")
    assert r.returncode == 0, r.stderr
    got = read(out)
    stamps, z = written["stamps"], written["z"]
    api = inverse_dynamics_with_std(build_model(), stamps, z, t_in_ns=True, subject="ansur")
    plain = inverse_dynamics_with_std(build_model(), stamps, z, t_in_ns=True)
    sd = np.array([got["std"][int(s)].effort for s in stamps])
    np.testing.assert_allclose(sd[api.known], api.std[api.known], rtol=1e-12)
    assert np.all(sd[api.known] > plain.std[api.known])
    assert "ANSUR II male (n = 4082)" in got["config"]["std"]["subject_parameters"]
