"""Every tool's output is every tool's input: the offline tools and the replay nodes chained
as a user chains them, each step's exit code 0 and its numbers checked against what the
step before it wrote (not only its keys).

    .mot --mot_to_bag--> q.mcap --bag_torques--> tq.mcap --check_bag--> report
                                                        \\--bag_export--> CSV
    tq.mcap --bag_player--> bag_recorder --> copy.mcap --check_bag [--baseline tq.mcap]
    q.mcap --bag_player--> torque_node + bag_recorder --> live.mcap --check_bag --baseline tq.mcap

(record -> bag_player -> record -> check_bag --baseline on a live recording:
test_replay_regression.py.) A left arm holding 0.5 kg at the 95th percentile, 100 Hz: every
setting the tools must carry from one to the next differs from its default.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import rosproc
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader
from rosproc import BIN
from std_msgs.msg import String
from test_opensim_files import MAPPED, START, angles, write_file

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.bag import open_bag

pytestmark = pytest.mark.ros

RATE = 100.0
N = 300  # 3 s at 100 Hz
MODEL_ARGS = ("--body-size", "95", "--side", "left", "--payload-mass", "0.5")
NODE_PARAMS = ("-p", "body_size:=95", "-p", "side:=left", "-p", "payload_mass:=0.5")
ARM = build_model("segmented", 95, side="left", payload_mass=0.5)
TOPICS = ["/joint_states", "/joint_torques", "/torque_node/config"]


def tool(exe: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / exe), *map(str, args)], env=rosproc.ros_env(),
                          capture_output=True, text=True, timeout=300, check=False)


def check_bag(*args) -> tuple[subprocess.CompletedProcess, dict]:
    out = Path(str(args[0]) + ".report.json")
    r = tool("check_bag", *args, "--json", out)
    return r, (json.loads(out.read_text()) if out.exists() else {})


def series(bag: Path, topic: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """stamps (ns), positions, efforts of a JointState topic, read by rosbags."""
    stamps, pos, eff = [], [], []
    with AnyReader([bag]) as r:
        for c, _t, raw in r.messages([c for c in r.connections if c.topic == topic]):
            m = r.deserialize(raw, c.msgtype)
            assert list(m.name) == list(JOINT_NAMES)
            stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)
            pos.append(m.position)
            eff.append(m.effort)
    return np.array(stamps), np.array(pos, float), np.array(eff, float)


def configs(bag: Path) -> list[dict]:
    return [json.loads(deserialize_message(bytes(m.data), String).data)
            for _ch, m in open_bag(bag).messages(["/torque_node/config"])]


def backward_torques(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """What the backward estimator must give from positions only (by hand: two warm-up samples)."""
    dt = np.diff(t)[:, None]
    qd = np.vstack([np.zeros(20), np.diff(q, axis=0) / dt])
    qdd = np.vstack([np.zeros(20), np.diff(qd, axis=0) / dt])
    qdd[:2] = 0
    return ARM.inverse_dynamics(q, qd, qdd)


@pytest.fixture(scope="module")
def offline(tmp_path_factory) -> dict:
    """.mot -> mot_to_bag -> bag_torques (backward estimator: its numbers are exactly known)."""
    d = tmp_path_factory.mktemp("chain")
    mot, q_bag, tq_bag = d / "arm.mot", d / "q.mcap", d / "tq.mcap"
    t = write_file(mot, "motion", degrees=True, rate=RATE, seconds=N / RATE)
    r = tool("mot_to_bag", mot, q_bag, "--start", START)
    assert r.returncode == 0, r.stdout + r.stderr
    r = tool("bag_torques", q_bag, tq_bag, *MODEL_ARGS, "--estimator", "backward")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "model segmented p95 left arm, payload 0.5 kg, estimator backward" in r.stdout, r.stdout
    q = np.zeros((len(t), 20))
    for c, j in MAPPED.items():
        q[:, JOINT_NAMES.index(j)] = angles(t)[c]
    return {"dir": d, "t": t, "q": q, "q_bag": q_bag, "tq_bag": tq_bag}


def test_mot_to_bag_bag_torques_check_bag_bag_export(offline) -> None:
    t, q, q_bag, tq_bag = offline["t"], offline["q"], offline["q_bag"], offline["tq_bag"]
    stamps, pos, _ = series(q_bag, "/joint_states")
    assert len(stamps) == N
    np.testing.assert_array_equal(stamps, round(START * 1e3) * 1_000_000 + np.round(t * 1e9))
    np.testing.assert_allclose(pos, q, rtol=0, atol=1e-12)
    # bag_torques: its config message names what it was asked, at the bag's own rate
    [cfg] = configs(tq_bag)
    assert (cfg["side"], cfg["payload"]["mass"], cfg["body_size"]["label"]) == ("left", 0.5, "p95")
    assert cfg["node"] == "bag_torques" and cfg["source_bag"] == str(q_bag)
    assert cfg["estimator"]["method"] == "backward"
    assert cfg["estimator"]["at_sample_period_s"] == pytest.approx(1 / RATE, rel=1e-9)
    tq_stamps, tq_pos, tau = series(tq_bag, "/joint_torques")
    np.testing.assert_array_equal(tq_stamps, stamps)
    np.testing.assert_allclose(tq_pos, q, rtol=0, atol=1e-12)  # the state each torque is of
    expected = backward_torques(t, q)
    np.testing.assert_allclose(tau, expected, rtol=0, atol=1e-8)
    # the settings matter: the right arm without the object gives other torques
    assert np.abs(build_model("segmented", 95).inverse_dynamics(q, *np.zeros((2, *q.shape)))
                  - ARM.inverse_dynamics(q, *np.zeros((2, *q.shape)))).max() > 0.1
    # check_bag reads the config bag_torques wrote (the refusal this test guards against:
    # "unknown key(s) ['source_bag']") and scores every sample
    r, rep = check_bag(tq_bag)
    assert r.returncode == 0, r.stdout + r.stderr
    assert rep["model"] == {"kind": "segmented", "body_size": "p95", "side": "left",
                            "payload_kg": 0.5, "source": "torque_node/config"}
    assert "left arm, payload 0.5 kg (from torque_node/config)" in r.stdout
    assert rep["samples"] == N and rep["delivery"]["joint_torques"] == N
    assert rep["delivery"]["lost"] == 0 and rep["failures"] == []
    # bag_export: the CSV holds the bag's torques, to the digit
    csv = offline["dir"] / "tq.csv"
    r = tool("bag_export", tq_bag, "--format", "csv", "--out", csv)
    assert r.returncode == 0, r.stdout + r.stderr
    lines = csv.read_text().splitlines()
    head = lines[0].split(",")
    rows = np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]])
    assert len(rows) == N
    np.testing.assert_array_equal(rows[:, head.index("stamp_ns")], stamps)
    moments = rows[:, [head.index(f"{j}_moment") for j in JOINT_NAMES]]
    np.testing.assert_allclose(moments, expected, rtol=1e-12, atol=1e-12)


def _play(procs: rosproc.Procs, bag: Path, *ros_args: str) -> rosproc.NodeProcess:
    args = [str(BIN / "bag_player"), str(bag), "--ros-args", *ros_args]
    return procs.add(rosproc.NodeProcess("bag_player", args, rosproc.ros_env(), bag.parent,
                                         split_stderr=True))


def _record_while(procs: rosproc.Procs, out: Path, player_bag: Path, player_args: tuple,
                  *nodes: tuple) -> list[rosproc.NodeProcess]:
    """bag_recorder (and `nodes`, each (executable, *ros_args), returned) running while
    bag_player plays player_bag to its end; every process exits 0."""
    started = [procs.start(exe, *args) for exe, *args in nodes]
    rec = procs.start("bag_recorder", "-p", f"output:={out}", "-p", f"topics:={TOPICS}")
    for p in started:
        assert p.wait_for_output("config on", rosproc.STARTUP_S), p.output()
    assert rec.wait_for_output("recording", rosproc.STARTUP_S), rec.output()
    player = _play(procs, player_bag, "-p", "subscriber_timeout:=60.0", "-p", "start_delay:=3.0",
                   *player_args)
    assert player.wait(timeout=180) == 0, player.output()
    assert rec.stop() == 0, rec.output()
    for p in started:
        assert p.stop() == 0, p.output()
    return started


def test_bag_torques_output_replayed_by_bag_player(offline, procs, tmp_path) -> None:
    """bag_player plays all three topics of bag_torques' output; the recording is the same
    bag: every torque byte for byte, the config, and check_bag finds the same model."""
    tq_bag, copy = offline["tq_bag"], tmp_path / "copy.mcap"
    # min_subscribers counts the first topic's: the recorder is its one subscriber
    _record_while(procs, copy, tq_bag, ("-p", f"topics:={TOPICS}", "-p", "min_subscribers:=1"))
    src = {ch.topic: [bytes(m.data) for _c, m in open_bag(tq_bag).messages([ch.topic])]
           for ch in open_bag(tq_bag).info.channels.values()}
    got = {t: [bytes(m.data) for _c, m in open_bag(copy).messages([t])] for t in TOPICS}
    for topic in TOPICS[:2]:
        assert got[topic] == src[topic], (topic, len(got[topic]), len(src[topic]))
    # the config by its content (DDS pads the string's CDR to 4 bytes; the file holds rclpy's)
    assert configs(copy) == configs(tq_bag)
    r, rep = check_bag(copy)
    assert r.returncode == 0, r.stdout + r.stderr
    assert rep["model"]["side"] == "left" and rep["model"]["payload_kg"] == 0.5
    assert rep["samples"] == N and rep["delivery"]["lost"] == 0
    r, rep = check_bag(copy, "--baseline", tq_bag, "--tolerance", "0")
    assert r.returncode == 0, r.stdout + r.stderr
    assert rep["matched"] == N and rep["unmatched_new"] == rep["unmatched_baseline"] == 0


def test_mot_bag_replayed_into_the_node_matches_bag_torques(offline, procs, tmp_path) -> None:
    """The .mot's joint_states played into a torque_node with the same settings: its torques
    are bag_torques' (check_bag --baseline, to 1e-9 N·m), sample for sample."""
    live = tmp_path / "live.mcap"
    [node] = _record_while(procs, live, offline["q_bag"], ("-p", "min_subscribers:=2"),
                           ("torque_node", *NODE_PARAMS, "-p", "estimator:=backward"))
    # its start-up line says what it computes with, payload and estimator included
    assert ("model segmented, body size p95, left arm, payload 0.5 kg, estimator backward; "
            "config on /torque_node/config") in node.output(), node.output()
    r, rep = check_bag(live, "--baseline", offline["tq_bag"], "--tolerance", "1e-9")
    assert r.returncode == 0, r.stdout + r.stderr
    assert rep["matched"] == N and rep["unmatched_new"] == rep["unmatched_baseline"] == 0
    _, _, tau = series(live, "/joint_torques")
    np.testing.assert_allclose(tau, backward_torques(offline["t"], offline["q"]), rtol=0, atol=1e-8)
    [cfg] = [c for c in configs(live) if c.get("applies_from_stamp_ns") is not None][:1]
    assert (cfg["side"], cfg["payload"]["mass"], cfg["body_size"]["label"]) == ("left", 0.5, "p95")
    r, rep = check_bag(live)
    assert r.returncode == 0, r.stdout + r.stderr
    assert rep["model"]["side"] == "left" and rep["samples"] == N
