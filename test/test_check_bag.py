"""check_bag on synthetic runs: bags written with our writer from model torques computed here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosproc import ros_env
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics import build_model, get_movement
from forearm_dynamics.bag import BagWriter, TopicQos
from forearm_dynamics.cli.check_bag import main as check_bag
from forearm_dynamics.nodes.torque_node import model_config
from forearm_dynamics.reference import save_reference

T_START = 1_750_000_000_000_000_000
MOVEMENTS = (1, 28)  # wrist pronation at elbow 0; close hand + flexing elbow
WRIST = 2  # index of wrist_flexion


@dataclass
class Run:
    """How to fake one recording of trajectory_publisher -> torque_node -> bag_recorder."""

    movements: tuple[int, ...] = MOVEMENTS
    kind: str = "segmented"
    size: int = 50
    latency_ns: int = 300_000
    offset: dict[int, float] = field(default_factory=dict)  # DOF -> fraction of its ptp added
    drop: tuple[int, ...] = ()  # torque sample indices (over the run) left out
    config: bool = True
    markers: bool = True
    torques: bool = True


def _config(arm) -> str:
    """The torque node's latched config JSON, made by the torque node's own code."""
    return json.dumps(model_config(arm, None))


def write_run(path: Path, run: Run) -> int:
    """Write the bag; returns the number of joint_states."""
    arm = build_model(run.kind, run.size)
    names = list(arm.joint_names)
    n_states = 0
    with BagWriter(path, flush_period_s=3600) as w:
        js = w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        tq = w.add_topic("/joint_torques", "sensor_msgs/msg/JointState") if run.torques else None
        mv_ch = w.add_topic("/movement", "std_msgs/msg/String")
        cfg = w.add_topic("/torque_node/config", "std_msgs/msg/String",
                          TopicQos(depth=1, durability="transient_local"))
        if run.config:
            w.write(cfg, serialize_message(String(data=_config(arm))), T_START - 10**9)
        t0 = T_START
        for mid in run.movements:
            mv = get_movement(mid)
            t = mv.sample_times(1000)
            q, qd, qdd = mv.evaluate(t)
            tau = arm.inverse_dynamics(q, qd, qdd)
            for dof, frac in run.offset.items():
                tau[:, dof] += frac * np.ptp(tau[:, dof])
            if run.markers:
                marker = {"id": mid, "name": mv.name, "elbow": mv.elbow, "body_size": run.size,
                          "t0_ns": t0, "t0": t0 / 1e9}
                w.write(mv_ch, serialize_message(String(data=json.dumps(marker))), t0 - 1000)
            for k in range(len(t)):
                stamp = t0 + round(t[k] * 1e9)
                m = JointState(name=names, position=q[k].tolist(), velocity=qd[k].tolist())
                m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp, 10**9)
                w.write(js, serialize_message(m), stamp + 50_000)
                if tq is not None and n_states not in run.drop:
                    m.effort = tau[k].tolist()
                    w.write(tq, serialize_message(m), stamp + run.latency_ns)
                n_states += 1
            t0 += round(mv.duration * 1e9) + 100_000_000
    return n_states


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """A gold-standard file: Pinocchio's anatomical model (matches OpenSim to 1e-8) at P50.

    All 65 movements: the model-error gate normalises by each DOF's largest peak-to-peak
    over the whole library.
    """
    arm = build_model("anatomical", 50)
    ids = list(range(1, 66))
    torques = [arm.inverse_dynamics(*get_movement(m).evaluate(get_movement(m).sample_times(1000)))
               for m in ids]
    path = tmp_path_factory.mktemp("ref") / "reference_torques.npz"
    save_reference(path, np.array(torques)[None], [50], ids, 1000.0,
                   {"engine": "pinocchio (test stand-in for OpenSim)", "kind": "anatomical"})
    return path


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("bags") / "good.mcap"
    write_run(path, Run())
    return path


def _check(bag: Path, reference: Path, *extra: str, capsys=None) -> tuple[int, str]:
    code = check_bag([str(bag), "--reference", str(reference), *extra])
    out = capsys.readouterr() if capsys is not None else None
    return code, (out.out + out.err) if out else ""


def test_clean_run_passes(good_bag, reference, tmp_path, capsys) -> None:
    out_json = tmp_path / "report.json"
    code, text = _check(good_bag, reference, "--json", str(out_json), capsys=capsys)
    assert code == 0, text
    assert "PASS" in text and "wrist_pronation" in text
    report = json.loads(out_json.read_text())
    assert report["exit_code"] == 0 and report["failures"] == []
    assert report["model"] == {"kind": "segmented", "body_size": "p50", "source": "torque_node/config"}
    assert [m["id"] for m in report["movements"]] == list(MOVEMENTS)
    for m in report["movements"]:
        assert m["samples"] == m["expected"] == 1500
        assert m["pipeline_worst"]["nrmse"] < 1e-9  # same model, exact state
        assert m["model_nrmse"] is not None
    groups = report["model_error_groups"]
    assert set(groups) == {"pro_sup", "elbow", "wrist", "thumb", "fingers"}
    assert all(g["median"] is None or g["median"] < 0.10 for g in groups.values())
    d = report["delivery"]
    assert d["lost"] == 0 and d["joint_states"] == d["joint_torques"] == 3000
    assert d["latency_ms"]["p50"] == pytest.approx(0.3) and d["latency_ms"]["p99"] == pytest.approx(0.3)
    assert 600 < d["rate_hz"]["joint_states"] < 1000  # 1 kHz with a 0.1 s pause between movements


def test_injected_torque_error_fails_naming_the_dof(tmp_path, reference, capsys) -> None:
    bag = tmp_path / "offset.mcap"
    write_run(bag, Run(offset={WRIST: 0.05}))
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 1
    fails = [line for line in text.splitlines() if line.startswith("FAIL:")]
    assert fails and all("wrist_flexion" in line for line in fails)
    assert "pipeline NRMSE 0.05" in fails[0]


def test_dropped_messages_are_reported(tmp_path, reference, capsys) -> None:
    bag = tmp_path / "dropped.mcap"
    write_run(bag, Run(drop=(10, 11, 12, 500, 2000, 2001, 2999 - 200)))
    out_json = tmp_path / "r.json"
    code, text = _check(bag, reference, "--json", str(out_json), capsys=capsys)
    assert code == 1
    assert "lost 7 of 2900" in text  # the last 0.1 s (tail_grace_s) is not counted
    d = json.loads(out_json.read_text())["delivery"]
    assert d["lost"] == 7 and d["considered"] == 2900
    assert d["loss_pct"] == pytest.approx(100 * 7 / 2900)
    # the pipeline itself is still right on the samples that arrived
    assert not any("pipeline" in f for f in json.loads(out_json.read_text())["failures"])


def test_latency_threshold(tmp_path, reference, capsys) -> None:
    bag = tmp_path / "slow.mcap"
    write_run(bag, Run(latency_ns=2_500_000, movements=(1,)))
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 1 and "latency p99 2.500 ms > 1.0 ms" in text


def test_without_config_assumes_default_model(tmp_path, reference, capsys) -> None:
    bag = tmp_path / "noconfig.mcap"
    write_run(bag, Run(config=False, movements=(1,)))
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 0, text
    assert "warning: no torque_node/config in the bag" in text


def test_other_model_from_config_is_used(tmp_path, reference, capsys) -> None:
    """A solid-model run is checked against the solid model, not the default segmented."""
    bag = tmp_path / "solid.mcap"
    write_run(bag, Run(kind="solid", movements=(1,)))
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 0, text
    assert "model solid, body size p50 (from torque_node/config)" in text


def test_missing_reference_skips_model_error(good_bag, tmp_path, capsys) -> None:
    code, text = _check(good_bag, tmp_path / "none.npz", capsys=capsys)
    assert code == 0
    assert "model error skipped" in text


def test_truncated_bag_is_analysed_with_a_warning(good_bag, reference, tmp_path, capsys) -> None:
    data = good_bag.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    code, text = _check(cut, reference, capsys=capsys)
    assert code == 0, text
    assert "warning: bag is truncated" in text
    recovered = tmp_path / "recovered.mcap"
    assert check_bag([str(cut), "--recover", str(recovered)]) == 0
    assert "recovered" in capsys.readouterr().out
    assert _check(recovered, reference, capsys=capsys)[0] == 0


def _cli(*args: str) -> subprocess.CompletedProcess:
    # a clean ROS environment: the child re-runs the wheels' bootstrap itself
    return subprocess.run([sys.executable, "-m", "forearm_dynamics.cli.check_bag", *args],
                          check=False, capture_output=True, text=True, env=ros_env(), timeout=60)


@pytest.mark.parametrize("case", ["empty", "random", "magic_only", "cut_early", "missing"])
def test_corrupt_files_exit_2_with_one_line(tmp_path, good_bag, case) -> None:
    path = tmp_path / f"{case}.mcap"
    content = {"empty": b"", "random": os.urandom(10000), "magic_only": b"\x89MCAP0\r\n",
               "cut_early": good_bag.read_bytes()[:3000], "missing": None}[case]
    if content is not None:
        path.write_bytes(content)
    res = _cli(str(path))
    assert res.returncode == 2
    assert res.stdout == ""
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("check_bag: error:") and str(path) in lines[0]
    assert "Traceback" not in res.stderr


@pytest.mark.parametrize(("run", "needle"), [
    (Run(torques=False, movements=(1,)), "no joint_torques"),
])
def test_foreign_bags_exit_2(tmp_path, reference, run, needle, capsys) -> None:
    bag = tmp_path / "foreign.mcap"
    write_run(bag, run)
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 2
    assert needle in text and len(text.strip().splitlines()) == 1


def test_run_without_markers_is_scored_as_one_segment(tmp_path, reference, capsys) -> None:
    """No markers (any recording): not refused any more, analysed against its own filtered
    positions (bag/score.py; details in test_check_markerless.py)."""
    bag = tmp_path / "nomarkers.mcap"
    write_run(bag, Run(markers=False, movements=(1,)))
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 0, text
    assert "no movement markers: one segment" in text


def test_garbage_payloads_exit_2(tmp_path, reference, capsys) -> None:
    """A channel that claims JointState but carries noise: one line, no traceback."""
    bag = tmp_path / "noise.mcap"
    with BagWriter(bag) as w:
        tq = w.add_topic("/joint_torques", "sensor_msgs/msg/JointState")
        mv = w.add_topic("/movement", "std_msgs/msg/String")
        w.write(mv, serialize_message(String(data='{"id": 1, "t0_ns": 1}')), 1)
        for k in range(50):
            w.write(tq, os.urandom(300), 2 + k)
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 2
    assert len(text.strip().splitlines()) == 1 and "cannot analyse" in text
