"""The shoulder columns of an OpenSim file reach the bag and the torques (real tools, real
files, an independent bag reader): mot_to_bag keeps them as the shoulder's joint names,
bag_torques builds the moving-humerus model from them."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosproc import BIN, ros_env

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.shoulder import CONVENTIONS, synthetic_shoulder_motion

pytestmark = pytest.mark.cli

RATE = 200.0
ARM = {"elbow_flexion": "elbow_flexion", "pro_sup": "pro_sup", "flexion": "wrist_flexion",
       "deviation": "wrist_deviation"}


def arm_motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, qd, qdd) of the four arm joints: slow sines with exact derivatives."""
    w = 2 * np.pi * np.array([0.5, 0.4, 0.6, 0.3])
    mid, amp = np.array([1.0, 0.3, 0.1, 0.05]), np.array([0.5, 0.4, 0.3, 0.1])
    arg = w * t[:, None]
    return mid + amp * np.sin(arg), amp * w * np.cos(arg), -amp * w * w * np.sin(arg)


def write_mot(path, columns: tuple[str, ...], t, q_arm, q_sh) -> None:
    labels = [*ARM, *columns, "pelvis_tilt"]
    data = np.column_stack([t, np.degrees(q_arm), np.degrees(q_sh), np.zeros_like(t)])
    head = ["Coordinates", "version=1", f"nRows={len(t)}", f"nColumns={len(labels) + 1}",
            "inDegrees=yes", "endheader", "\t".join(["time", *labels])]
    path.write_text("\n".join(head + ["\t".join(f"{x:.17g}" for x in r) for r in data]) + "\n")


def run(exe: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / exe), *map(str, args)], env=ros_env(), capture_output=True,
                          text=True, timeout=300, check=False)


def read(bag, topic: str) -> tuple[list[str], np.ndarray, np.ndarray]:
    names, pos, eff = None, [], []
    with AnyReader([bag]) as r:
        for c, _t, raw in r.messages():
            if c.topic == topic:
                m = r.deserialize(raw, c.msgtype)
                names = list(m.name)
                pos.append(m.position)
                eff.append(m.effort)
    return names, np.array(pos), np.array(eff)


@pytest.mark.parametrize("name", sorted(CONVENTIONS))
def test_shoulder_columns_reach_the_bag_and_the_torques(tmp_path, name):
    conv = CONVENTIONS[name]
    t = np.arange(round(4 * RATE)) / RATE
    qa, qda, qdda = arm_motion(t)
    qs, qds, qdds = synthetic_shoulder_motion(name, t)
    src, bag, out = tmp_path / "in.mot", tmp_path / "in.mcap", tmp_path / "out.mcap"
    write_mot(src, conv.aliases["right"], t, qa, qs)
    r = run("mot_to_bag", src, bag, "--start", 1000)
    assert r.returncode == 0, r.stderr
    assert f"shoulder ({name}, the humerus moves)" in r.stdout
    assert conv.aliases["right"][0] not in r.stdout.split("unknown columns")[-1]  # not "not used"
    names, pos, _ = read(bag, "/joint_states")
    assert names == [*JOINT_NAMES, *conv.joint_names]
    np.testing.assert_allclose(pos[:, 20:], qs, rtol=0, atol=1e-12)

    r = run("bag_torques", bag, out, "--estimator", "zero_phase", "--cutoff", "8")
    assert r.returncode == 0, r.stderr
    assert f"shoulder {name}" in r.stdout
    names, _, tau = read(out, "/joint_torques")
    assert names == [*JOINT_NAMES, *conv.joint_names]

    # the exact torques of the motion in the file, with and without the humerus moving
    n = len(t)
    q, qd, qdd = (np.zeros((n, 20)) for _ in range(3))
    for k, j in enumerate(ARM.values()):
        i = JOINT_NAMES.index(j)
        q[:, i], qd[:, i], qdd[:, i] = qa[:, k], qda[:, k], qdda[:, k]
    exact = build_model(shoulder=name).inverse_dynamics(
        np.hstack([q, qs]), np.hstack([qd, qds]), np.hstack([qdd, qdds]))
    welded = build_model().inverse_dynamics(q, qd, qdd)
    inner = slice(round(0.5 * RATE), n - round(0.5 * RATE))  # the filter's edges aside
    err = np.sqrt(np.mean((tau[inner, 0] - exact[inner, 0]) ** 2))
    moved = np.sqrt(np.mean((welded[inner, 0] - exact[inner, 0]) ** 2))
    assert moved > 0.2  # N·m: the humerus' motion matters at the elbow
    assert err < 0.1 * moved, (err, moved)
