"""Issue 30 items 2-3 through the tools as processes: mot_to_bag maps the Hamner header with
the default map and refuses units mistakes and map typos; check_bag FAILs a bag of degrees
with "check units"; bag_torques refuses it. Bags read with rosbags (an independent reader)."""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosproc import BIN, ros_env
from test_units_and_maps import hamner_angles_deg, write_hamner

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.bag import BagWriter, TopicQos
from forearm_dynamics.codec.jointstate import tidy
from forearm_dynamics.codec.ros import message, serialize
from forearm_dynamics.formats.opensim import CoordinateMap, map_motion, read_motion

pytestmark = pytest.mark.cli

START = 1000.0


def run(exe: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / exe), *map(str, args)], env=ros_env(), capture_output=True,
                          text=True, timeout=180, check=False)


def error_lines(r: subprocess.CompletedProcess) -> list[str]:
    return [ln for ln in r.stderr.splitlines() if "error" in ln]


def test_mot_to_bag_hamner_default_map_and_units(tmp_path):
    src = tmp_path / "subject02_running_ik.mot"
    t = write_hamner(src, True)
    bag = tmp_path / "ok.mcap"
    r = run("mot_to_bag", src, bag, "--start", START)
    assert r.returncode == 0, r.stderr
    assert "mapped (4): elbow_flex_r -> elbow_flexion, pro_sup_r -> pro_sup" in r.stdout
    assert "the other arm's columns, not used (--side left for them) (4)" in r.stdout
    warn = [ln for ln in r.stderr.splitlines() if "model joints not in the file" in ln]
    assert len(warn) == 1 and warn[0].startswith("mot_to_bag: warning: 16 of 20 model joints")
    with AnyReader([bag]) as rd:
        pos = np.array([rd.deserialize(raw, c.msgtype).position for c, _t, raw in rd.messages()])
    np.testing.assert_allclose(pos[:, 1], np.radians(hamner_angles_deg(t)["pro_sup_r"] - 90), atol=1e-9)

    # degrees under inDegrees=no: refused, one line naming units; nothing written
    deg = tmp_path / "deg_as_rad.mot"
    write_hamner(deg, degrees_header=False)
    r = run("mot_to_bag", deg, tmp_path / "x.mcap", "--start", START)
    assert r.returncode == 2
    assert len(error_lines(r)) == 1 and "inDegrees=no" in r.stderr and "check units" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "x.mcap").exists()
    # radians under inDegrees=yes: refused too
    rad = tmp_path / "rad_as_deg.mot"
    write_hamner(rad, degrees_header=True, scale=math.pi / 180)
    r = run("mot_to_bag", rad, tmp_path / "y.mcap", "--start", START)
    assert r.returncode == 2 and len(error_lines(r)) == 1 and "check units" in r.stderr
    # a typo in a user's map: exit 2, one line naming it
    typo = tmp_path / "typo.yaml"
    typo.write_text("coordinates:\n  elbow_flexx_r: {joint: elbow_flexion}\n")
    r = run("mot_to_bag", src, tmp_path / "z.mcap", "--map", typo)
    assert r.returncode == 2 and len(error_lines(r)) == 1 and "elbow_flexx_r" in r.stderr


def _write_recording(path, q: np.ndarray, t_ns: np.ndarray, tau: np.ndarray) -> None:
    """joint_states and the joint_torques a node without the range check would have sent."""
    with BagWriter(path) as w:
        s = w.add_topic("/joint_states", "sensor_msgs/msg/JointState", TopicQos(depth=1000))
        o = w.add_topic("/joint_torques", "sensor_msgs/msg/JointState", TopicQos(depth=1000))
        msg = message("JointState")()
        msg.name = list(JOINT_NAMES)
        for k, stamp in enumerate(t_ns.tolist()):
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            msg.position, msg.effort = q[k].tolist(), []
            w.write(s, tidy(serialize(msg)), stamp)
            msg.effort = tau[k].tolist()
            w.write(o, tidy(serialize(msg)), stamp + 200_000)


def test_check_bag_fails_degrees_with_check_units_and_bag_torques_refuses(tmp_path):
    src = tmp_path / "run.mot"
    write_hamner(src, True)
    mm = map_motion(read_motion(src), CoordinateMap.load())
    t_ns = (START * 1e9 + mm.time * 1e9).astype(np.int64)
    arm = build_model("segmented", 50)
    dt = float(np.median(np.diff(mm.time)))
    for name, q in (("right.mcap", mm.q), ("degrees.mcap", np.degrees(mm.q))):
        qd = np.gradient(q, dt, axis=0)
        tau = arm.inverse_dynamics_batch(q, qd, np.gradient(qd, dt, axis=0), check_ranges="off")
        _write_recording(tmp_path / name, q, t_ns, tau)
    r = run("check_bag", tmp_path / "degrees.mcap")
    assert r.returncode == 1, r.stdout + r.stderr
    fails = [ln for ln in r.stdout.splitlines() if ln.startswith("FAIL: ")]
    assert fails and "check units" in fails[0] and "joint_states positions" in fails[0]
    assert not any("estimator:=kalman" in f for f in fails)  # no estimator advice for units
    r = run("check_bag", tmp_path / "right.mcap")
    assert "check units" not in r.stdout, r.stdout
    still = [ln for ln in r.stdout.splitlines() if ln.endswith("still")]
    assert len(still) == 16 and not any(ln.startswith("thumb_cmc_abduction") and "worst" in ln
                                        for ln in r.stdout.splitlines())
    worst = next(ln for ln in r.stdout.splitlines() if "worst" in ln)
    assert any(j in worst for j in ("elbow_flexion", "pro_sup", "wrist_flexion", "wrist_deviation")), worst
    # bag_torques on the bag of degrees: refused (exit 2), one line naming units
    r = run("bag_torques", tmp_path / "degrees.mcap", tmp_path / "tq.mcap")
    assert r.returncode == 2 and len(error_lines(r)) == 1 and "check units" in r.stderr
    assert not (tmp_path / "tq.mcap").exists()
