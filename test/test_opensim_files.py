"""OpenSim files in and out: mot_to_bag on synthetic .mot/.sto files (degrees and radians,
motion and states kinds), bag_export to CSV and .sto, and the round trip
.mot -> bag -> bag_torques -> .sto against inverse_dynamics. Bags read with rosbags."""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosproc import BIN, ros_env

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.formats.opensim import read_motion

pytestmark = pytest.mark.cli

START = 1000.0  # s: stamps start here
# MoBL / ARMS coordinate -> our joint (the shipped map; signs +1)
MAPPED = {"elbow_flexion": "elbow_flexion", "pro_sup": "pro_sup", "flexion": "wrist_flexion",
          "deviation": "wrist_deviation", "cmc_abduction": "thumb_cmc_abduction",
          "2mcp_flexion": "index_mcp_flexion", "5pm_flexion": "little_pip_flexion"}


def angles(t: np.ndarray) -> dict[str, np.ndarray]:
    """rad, per MoBL coordinate: slow, distinct motions."""
    return {c: 0.2 + 0.3 * np.sin(2 * np.pi * (0.4 + 0.1 * k) * t + k) for k, c in enumerate(MAPPED)}


def speeds(t: np.ndarray) -> dict[str, np.ndarray]:
    return {c: 0.3 * 2 * np.pi * (0.4 + 0.1 * k) * np.cos(2 * np.pi * (0.4 + 0.1 * k) * t + k)
            for k, c in enumerate(MAPPED)}


def write_file(path, kind: str, degrees: bool, rate: float = 200.0, seconds: float = 2.0) -> np.ndarray:
    t = np.arange(round(rate * seconds)) / rate + 0.25  # a file need not start at 0
    a, v = angles(t), speeds(t)
    scale = 180 / math.pi if degrees else 1.0
    cols, labels = [], []
    for c in MAPPED:
        if kind == "motion":
            labels.append(c)
        else:
            labels.append(f"/jointset/joint_{c}/{c}/value")
        cols.append(a[c] * scale)
        if kind == "states":
            labels.append(f"/jointset/joint_{c}/{c}/speed")
            cols.append(v[c] * scale)
    # a MoBL coordinate we do not model, a column nobody knows (and, states: a muscle state)
    labels += ["/jointset/shoulder2/shoulder_elv/value" if kind == "states" else "shoulder_elv",
               "mystery_col"]
    cols += [np.full_like(t, 10.0), np.zeros_like(t)]
    if kind == "states":
        labels.append("/forceset/BIClong/activation")
        cols.append(np.full_like(t, 0.05))
    head = ["Coordinates" if kind == "motion" else "StatesTrajectory", "version=1",
            f"nRows={len(t)}", f"nColumns={len(labels) + 1}", f"inDegrees={'yes' if degrees else 'no'}",
            "endheader", "\t".join(["time", *labels])]
    rows = np.column_stack([t, *cols])
    path.write_text("\n".join(head + ["\t".join(f"{x:.17g}" for x in r) for r in rows]) + "\n")
    return t


def run(exe: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / exe), *map(str, args)], env=ros_env(), capture_output=True,
                          text=True, timeout=120, check=False)


def read_states(bag) -> tuple[np.ndarray, np.ndarray, list]:
    stamps, pos, vel = [], [], []
    with AnyReader([bag]) as r:
        for c, _t, raw in r.messages():
            if c.topic == "/joint_states":
                m = r.deserialize(raw, c.msgtype)
                assert list(m.name) == list(JOINT_NAMES)
                stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)
                pos.append(m.position)
                vel.append(m.velocity)
    return np.array(stamps), np.array(pos), vel


@pytest.mark.parametrize("kind,suffix", [("motion", ".mot"), ("states", ".sto")])
@pytest.mark.parametrize("degrees", [True, False])
def test_mot_to_bag(tmp_path, kind, suffix, degrees):
    src = tmp_path / f"in{suffix}"
    t = write_file(src, kind, degrees)
    bag = tmp_path / "out.mcap"
    r = run("mot_to_bag", src, bag, "--start", START)
    assert r.returncode == 0, r.stderr
    stamps, pos, vel = read_states(bag)
    expected = np.round(START * 1e3) * 1_000_000 + np.round(t * 1e9).astype(np.int64)
    np.testing.assert_array_equal(stamps, expected)
    a = angles(t)
    for c, j in MAPPED.items():
        np.testing.assert_allclose(pos[:, JOINT_NAMES.index(j)], a[c], rtol=0, atol=1e-12)
    held = [JOINT_NAMES.index(j) for j in JOINT_NAMES if j not in MAPPED.values()]
    assert (pos[:, held] == 0).all()
    if kind == "states":
        v = np.array(vel)
        for c, j in MAPPED.items():
            np.testing.assert_allclose(v[:, JOINT_NAMES.index(j)], speeds(t)[c], rtol=0, atol=1e-12)
    else:
        assert all(len(x) == 0 for x in vel)
    assert "unknown columns, not used (1): mystery_col" in r.stdout
    assert "shoulder_elv" in r.stdout.split("not modelled")[1]
    assert "13 of 20 model joints not in the file, held at the map's posture" in r.stderr


def test_round_trip_mot_bag_torques_sto(tmp_path):
    """.mot (degrees, 200 Hz) -> bag -> bag_torques (backward estimator, positions only) -> .sto:
    the .sto's times are the .mot's, its moments inverse_dynamics of the same states
    (computed here by hand: the backward estimator's numbers are exactly known)."""
    src = tmp_path / "walk.mot"
    t = write_file(src, "motion", degrees=True)
    bag, tq, sto = tmp_path / "q.mcap", tmp_path / "tq.mcap", tmp_path / "tq.sto"
    assert run("mot_to_bag", src, bag, "--start", START).returncode == 0
    r = run("bag_torques", bag, tq, "--body-size", "5", "--estimator", "backward")
    assert r.returncode == 0, r.stderr
    r = run("bag_export", tq, "--format", "sto", "--out", sto, "--states")
    assert r.returncode == 0, r.stderr
    m = read_motion(sto)
    assert not m.in_degrees and m.kind == "motion"
    np.testing.assert_allclose(m.time, t, rtol=0, atol=1e-9)
    q = np.zeros((len(t), 20))
    for c, j in MAPPED.items():
        q[:, JOINT_NAMES.index(j)] = angles(t)[c]
    # backward differences by hand (positions only: 2 warm-up samples)
    dt = np.diff(t)[:, None]
    qd = np.vstack([np.zeros(20), np.diff(q, axis=0) / dt])
    qd[0] = 0
    qdd = np.vstack([np.zeros(20), np.diff(qd, axis=0) / dt])
    qdd[:2] = 0
    expected = build_model("segmented", 5).inverse_dynamics(q, qd, qdd)
    moments = m.data[:, [m.labels.index(f"{j}_moment") for j in JOINT_NAMES]]
    np.testing.assert_allclose(moments, expected, rtol=0, atol=1e-8)
    np.testing.assert_allclose(m.data[:, [m.labels.index(j) for j in JOINT_NAMES]], q, rtol=0, atol=1e-12)
    # OpenSim names on request, CSV with integer stamps
    r = run("bag_export", tq, "--format", "sto", "--out", tmp_path / "os.sto", "--names", "opensim")
    assert r.returncode == 0, r.stderr
    labels = read_motion(tmp_path / "os.sto").labels
    assert {"elbow_flexion_moment", "flexion_moment", "deviation_moment",
            "2mcp_flexion_moment"} <= set(labels)
    r = run("bag_export", tq, "--format", "csv", "--out", tmp_path / "tq.csv")
    assert r.returncode == 0, r.stderr
    lines = (tmp_path / "tq.csv").read_text().splitlines()
    assert lines[0].startswith("time,stamp_ns,elbow_flexion_moment")
    assert len(lines) == len(t) + 1
    assert int(lines[1].split(",")[1]) == round(START * 1e3) * 1_000_000 + round(t[0] * 1e9)


GOOD = ["Coordinates", "inDegrees=yes", "endheader", "time\telbow_flexion\tpro_sup",
        "0.0\t10\t5", "0.01\t11\t5", "0.02\t12\t5"]


@pytest.mark.parametrize("case,lines,needle", [
    ("no_endheader", [ln for ln in GOOD if ln != "endheader"], "endheader"),
    ("ragged", [*GOOD[:5], "0.01\t11", *GOOD[6:]], "row 2"),
    ("nan", [*GOOD[:5], "0.01\tnan\t5", *GOOD[6:]], "row 2"),
    ("not_a_number", [*GOOD[:6], "0.02\tabc\t5"], "row 3"),
    ("time_not_increasing", [*GOOD[:6], "0.01\t12\t5"], "row 3"),
    ("no_degrees", [ln for ln in GOOD if not ln.startswith("inDegrees")], "inDegrees"),
    ("nothing_maps", [*GOOD[:3], "time\tfoo\tbar", *GOOD[4:]], "no column maps"),
])
def test_bad_motion_one_line_naming_the_row(tmp_path, case, lines, needle):
    src = tmp_path / "bad.mot"
    src.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.mcap"
    r = run("mot_to_bag", src, out, "--start", START)
    assert r.returncode == 2, r.stdout + r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    assert needle in r.stderr
    assert not out.exists()


def test_good_minimal_file_converts(tmp_path):
    """The file the bad cases derive from is fine: their failures are the edits."""
    src = tmp_path / "ok.mot"
    src.write_text("\n".join(GOOD) + "\n")
    r = run("mot_to_bag", src, tmp_path / "ok.mcap", "--start", START)
    assert r.returncode == 0, r.stderr
    _, pos, _ = read_states(tmp_path / "ok.mcap")
    np.testing.assert_allclose(pos[:, 0], np.radians([10, 11, 12]), atol=1e-15)
