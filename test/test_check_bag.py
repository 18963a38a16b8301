"""check_bag on synthetic runs: bags written with our writer from model torques computed here."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics import build_model, get_movement
from forearm_dynamics.bag import BagWriter, TopicQos
from forearm_dynamics.cli.check_bag import main as check_bag
from forearm_dynamics.model_config import model_config
from forearm_dynamics.paths import config_file
from forearm_dynamics.reference import save_reference

pytestmark = pytest.mark.unit

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
    drop_states: tuple[int, ...] = ()  # sample indices left out of joint_states and joint_torques
    announce: bool = False  # markers announce their sample count, as trajectory_publisher's do
    config: bool = True
    markers: bool = True
    torques: bool = True
    load: tuple[float, ...] = ()  # load_average_1min values put in /diagnostics, one per second
    late_ms: float = 0.0  # the first movement's last 100 samples sent (and stamped) this late
    sensor: dict | None = None  # marker "sensor": noise_deg on the published positions
    position_offset: float = 0.0  # rad added to every published position (a wrong publisher)
    # (first index, count): those samples unanswered and, as after a node that fell behind
    # its queue, the next 500 answers late by 1.0 s falling to nothing (the node catching up)
    overflow: tuple[int, int] = ()
    queue_depth: int | None = None  # the torque node's config states its input queue


def _config(arm, queue_depth: int | None = None) -> str:
    """The torque node's latched config JSON, made by the torque node's own code."""
    out = model_config(arm)
    if queue_depth is not None:
        out["input"] = {"missing_joints": "reject", "held_joints": [], "queue_depth": queue_depth}
    return json.dumps(out)


def _late_ns(run: Run, k: int) -> int:
    """How much later than run.latency_ns sample k (over the run) is answered (overflow)."""
    if not run.overflow:
        return 0
    after = k - sum(run.overflow)
    return round(1e9 * (1.0 - after / 500)) if 0 <= after < 500 else 0


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
            w.write(cfg, serialize_message(String(data=_config(arm, run.queue_depth))),
                    T_START - 10**9)
        if run.load:
            diag = w.add_topic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
            for k, load in enumerate(run.load):
                status = DiagnosticStatus(name="torque_node", values=[
                    KeyValue(key="processed_total", value="1000"),
                    KeyValue(key="load_average_1min", value=f"{load:.2f}")])
                w.write(diag, serialize_message(DiagnosticArray(status=[status])), T_START + k * 10**9)
        t0 = T_START
        for mid in run.movements:
            mv = get_movement(mid)
            t = mv.sample_times(1000)
            if run.late_ms and mid == run.movements[0]:
                # a late timer tick: the publisher catches up, stamping each sample when sent
                # and evaluating it at stamp - t0, so the movement outlasts its duration
                t[-100:] += run.late_ms / 1000
            q, qd, qdd = mv.evaluate(t)
            tau = arm.inverse_dynamics(q, qd, qdd)
            for dof, frac in run.offset.items():
                tau[:, dof] += frac * np.ptp(tau[:, dof])
            if run.markers:
                marker = {"id": mid, "name": mv.name, "elbow": mv.elbow, "body_size": run.size,
                          "t0_ns": t0, "t0": t0 / 1e9}
                if run.sensor is not None:
                    marker["sensor"] = run.sensor
                if run.announce:
                    marker["samples"] = len(t)
                w.write(mv_ch, serialize_message(String(data=json.dumps(marker))), t0 - 1000)
            if run.sensor is not None:  # what the simulated sensor published
                rng = np.random.default_rng(mid)
                q = q + rng.normal(0.0, np.radians(run.sensor["noise_deg"]), q.shape)
            q = q + run.position_offset
            for k in range(len(t)):
                stamp = t0 + round(t[k] * 1e9)
                m = JointState(name=names, position=q[k].tolist(), velocity=qd[k].tolist())
                m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp, 10**9)
                if n_states in run.drop_states:  # lost before the bag: neither it nor an answer
                    n_states += 1
                    continue
                w.write(js, serialize_message(m), stamp + 50_000)
                lost = run.overflow and 0 <= n_states - run.overflow[0] < run.overflow[1]
                if tq is not None and n_states not in run.drop and not lost:
                    m.effort = tau[k].tolist()
                    w.write(tq, serialize_message(m), stamp + run.latency_ns + _late_ns(run, n_states))
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
    # complete movements are not flagged, and no empty note is printed; the one note says
    # why movement 1 (pronation, elbow straight: gravity loads no DOF) shows no model NRMSE
    notes = [line for line in text.splitlines() if line.startswith(("  !", "  -"))]
    assert notes == [("  - movement 1 (index 0): model NRMSE '-': no DOF's reference torque moves "
                     "by 5 % of its largest peak-to-peak in this movement (model_rel_floor); "
                     "nothing to compare")], text
    assert "lost 0 of 2 900 joint_states" in text and "PASS: the data are right" in text
    assert all(m["shortfall"] is None and m["model_note"] is None for m in report["movements"])
    assert report["model"] == {"kind": "segmented", "body_size": "p50", "side": "right",
                               "payload_kg": 0.0, "source": "torque_node/config"}
    assert [m["id"] for m in report["movements"]] == list(MOVEMENTS)
    for m in report["movements"]:
        assert m["samples"] == m["expected"] == 1500
        assert m["pipeline_worst"]["nrmse"] < 1e-9  # same model, exact state
        assert m["model_nrmse"] is not None
    # a per-movement model NRMSE of tens of % under a PASS is explained (its normalisation)
    worst = [m["model_worst"]["nrmse"] for m in report["movements"] if m["model_worst"]["nrmse"]]
    explained = "the table's model column divides by that movement's own" in text
    assert explained == any(w > 0.10 for w in worst), (worst, text)
    groups = report["model_error_groups"]
    assert set(groups) == {"pro_sup", "elbow", "wrist", "thumb", "fingers"}
    assert all(g["median"] is None or g["median"] < 0.10 for g in groups.values())
    d = report["delivery"]
    assert d["lost"] == 0 and d["joint_states"] == d["joint_torques"] == 3000
    assert d["latency_ms"]["p50"] == pytest.approx(0.3) and d["latency_ms"]["p99"] == pytest.approx(0.3)
    assert 600 < d["rate_hz"]["joint_states"] < 1000  # 1 kHz with a 0.1 s pause between movements


def test_a_late_publisher_keeps_every_sample_in_its_movement(tmp_path, reference, capsys) -> None:
    """Samples stamped past t0 + duration (but before the next marker) are still counted."""
    bag = tmp_path / "late.mcap"
    write_run(bag, Run(late_ms=80.0))
    out_json = tmp_path / "late.json"
    code, text = _check(bag, reference, "--json", str(out_json), capsys=capsys)
    assert code == 0, text
    report = json.loads(out_json.read_text())
    assert [m["samples"] for m in report["movements"]] == [1500, 1500]
    assert all(m["shortfall"] is None for m in report["movements"]) and " ! " not in text
    assert report["movements"][0]["state_error_rad"] == 0.0  # evaluated at stamp - t0


def test_injected_torque_error_fails_naming_the_dof(tmp_path, reference, capsys) -> None:
    bag = tmp_path / "offset.mcap"
    write_run(bag, Run(offset={WRIST: 0.05}))
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 1
    fails = [line for line in text.splitlines() if line.startswith("FAIL:")]
    assert fails and all("wrist_flexion" in line for line in fails)
    assert "pipeline NRMSE 5.00 % > 2 %" in fails[0]


def test_dropped_messages_are_reported(tmp_path, reference, capsys) -> None:
    bag = tmp_path / "dropped.mcap"
    write_run(bag, Run(drop=(10, 11, 12, 500, 2000, 2001, 2999 - 200)))
    out_json = tmp_path / "r.json"
    code, text = _check(bag, reference, "--json", str(out_json), capsys=capsys)
    assert code == 1
    assert "lost 7 of 2 900 joint_states" in text
    # the last 0.1 s (tail_grace_s) is not counted, and the report says so
    assert "left out: the last 100 joint_states, received in the last 0.1 s of the stream" in text
    d = json.loads(out_json.read_text())["delivery"]
    assert d["lost"] == 7 and d["considered"] == 2900
    assert d["tail_left_out"] == 100 and d["tail_answered"] == 100
    assert d["loss_pct"] == pytest.approx(100 * 7 / 2900)
    # the failure names the lost stamps and where they fall
    t1 = get_movement(1).sample_times(1000)
    first = T_START + round(t1[10] * 1e9)
    assert d["lost_stamps_ns"][0] == first and len(d["lost_stamps_ns"]) == 7
    sec, nsec = divmod(first, 10**9)
    fail = next(line for line in text.splitlines() if line.startswith("FAIL: lost 7"))
    assert f"stamp {sec}.{nsec:09d} (movement 1 at {t1[10]:.3f} s)" in fail
    assert "and 2 more" in fail
    # both movements are flagged short, with the reason
    assert "! movement 1 (index 0): 1496 of 1500 expected samples: 4 of its 1500 joint_states " \
        "have no joint_torques" in text
    assert "! movement 28 (index 1): 1497 of 1500 expected samples: 3 of its 1500" in text
    # the pipeline itself is still right on the samples that arrived
    assert not any("pipeline" in f for f in json.loads(out_json.read_text())["failures"])


def test_a_queue_overflow_is_told_from_other_losses(tmp_path, reference, capsys) -> None:
    """Answers lost while the node was a queue behind (the next ones came ~1 s late) are named
    as an overflow when the config states the queue; the same losses with prompt neighbours,
    or without the queue in the config, are not blamed on the machine."""
    bag = tmp_path / "overflow.mcap"
    write_run(bag, Run(overflow=(600, 300), queue_depth=1000))
    out_json = tmp_path / "r.json"
    code, text = _check(bag, reference, "--json", str(out_json), capsys=capsys)
    assert code == 1
    d = json.loads(out_json.read_text())["delivery"]
    assert d["lost"] == 300 and d["lost_runs"] == 1
    assert d["behind_after_loss_ms"] == pytest.approx(1000.0, abs=1.0)
    fail = next(line for line in text.splitlines() if line.startswith("FAIL: lost 300"))
    # the queue in seconds at the rate recorded (968 Hz: the 0.1 s between the movements)
    assert "came up to 1.00 s later than usual, about what the torque node's input queue " \
        "holds (1000 samples = 1.03 s at 968 Hz): the node fell behind its input and DDS " \
        "dropped the oldest samples" in fail
    assert "qos_depth" in fail

    prompt = tmp_path / "prompt.mcap"  # the same samples lost, their neighbours on time
    write_run(prompt, Run(drop=tuple(range(600, 900)), queue_depth=1000))
    code, text = _check(prompt, reference, "--json", str(out_json), capsys=capsys)
    assert code == 1
    d = json.loads(out_json.read_text())["delivery"]
    assert d["lost"] == 300 and d["lost_runs"] == 1 and d["behind_after_loss_ms"] < 1.0
    fail = next(line for line in text.splitlines() if line.startswith("FAIL: lost 300"))
    assert "queue" not in fail and "later than usual" not in fail

    old = tmp_path / "old.mcap"  # a bag whose config does not state the queue
    write_run(old, Run(overflow=(600, 300)))
    code, text = _check(old, reference, capsys=capsys)
    fail = next(line for line in text.splitlines() if line.startswith("FAIL: lost 300"))
    assert fail.endswith("came up to 1.00 s later than usual (the bag's config does not "
                         "state the node's queue)"), fail


def test_inputs_missing_from_the_bag_fail_by_movement(tmp_path, reference, capsys) -> None:
    """Samples lost before the bag (a sample and its answer both absent: DDS, the recorder,
    the publisher) leave no unanswered joint_states; the marker's announced count finds them."""
    bag = tmp_path / "holes.mcap"
    write_run(bag, Run(drop_states=(700, 701, 702, 2200), announce=True))
    out_json = tmp_path / "r.json"
    code, text = _check(bag, reference, "--json", str(out_json), capsys=capsys)
    assert code == 1, text
    report = json.loads(out_json.read_text())
    assert report["delivery"]["lost"] == 0  # every recorded sample was answered
    assert [m["inputs_missing"] for m in report["movements"]] == [3, 1]
    fail = [f for f in report["failures"] if "before the bag" in f]
    assert len(fail) == 1 and fail[0].startswith("lost 4 joint_states before the bag"), report["failures"]
    assert "movement 1 at index 0 (3 of 1500), movement 28 at index 1 (1 of 1500)" in fail[0]
    # without an announced count (markers of older runs) it stays a note, as before
    plain = tmp_path / "holes_unannounced.mcap"
    write_run(plain, Run(drop_states=(700,)))
    code, text = _check(plain, reference, capsys=capsys)
    assert code == 0 and "only 1499 joint_states were recorded in its window" in text, text


@pytest.mark.parametrize("where", ["recording_ends", "publisher_stopped", "matched_late"])
def test_a_movement_missing_its_start_or_end_is_not_a_loss(tmp_path, reference, capsys, where) -> None:
    """Samples missing at a movement's end (the recording ends inside it; the publisher was
    killed and the next movement comes much later) or start (a reader matched a restarted
    publisher late): a note, not a failure; a hole beside them still counts."""
    drop = {"recording_ends": range(2500, 3000), "publisher_stopped": range(1000, 1500),
            "matched_late": range(1500, 1800)}[where]
    bag = tmp_path / f"{where}.mcap"
    write_run(bag, Run(announce=True, drop_states=tuple(drop)))
    out_json = tmp_path / "r.json"
    code, text = _check(bag, reference, "--json", str(out_json), capsys=capsys)
    report = json.loads(out_json.read_text())
    assert [m["inputs_missing"] for m in report["movements"]] == [0, 0], report["movements"]
    assert code == 0, text
    write_run(bag.with_suffix(".hole.mcap"), Run(announce=True, drop_states=(*drop, 200)))
    code, text = _check(bag.with_suffix(".hole.mcap"), reference, "--json", str(out_json), capsys=capsys)
    assert code == 1 and [m["inputs_missing"] for m in json.loads(out_json.read_text())["movements"]] \
        == [1, 0], text


def test_slow_latency_is_reported_not_failed(tmp_path, reference, capsys) -> None:
    """A slow machine is not wrong data: exit 0, the target missed and the load stated."""
    bag = tmp_path / "slow.mcap"
    write_run(bag, Run(latency_ns=2_500_000, movements=(1,), load=(3.5, 4.0, 3.0)))
    out_json = tmp_path / "slow.json"
    code, text = _check(bag, reference, "--json", str(out_json), capsys=capsys)
    assert code == 0, text
    assert "p99 2.500 ms" in text and "target p99 < 1 ms: NOT met" in text
    assert "load average 3.5 (1 min, median over the run; max 4.0) from the torque node's " \
        "/diagnostics" in text
    assert "reported only" in text and "FAIL" not in text
    report = json.loads(out_json.read_text())
    assert report["machine"]["load_average_during_run"] == [3.5, 4.0, 3.0]
    assert len(report["machine"]["load_average_now"]) == 3
    assert report["delivery"]["latency_p99_ms_max"] is None
    assert report["delivery"]["latency_p99_ms_target"] == 1.0


def test_old_stamps_say_latency_is_meaningless_and_name_restamp(tmp_path, reference, capsys) -> None:
    """A replay of an old recording with markers: the stamps are 120 s older than their arrival,
    so the latency measures the recording's age; the report says so and names restamp, the
    data still pass, and a fresh run (0.3 ms) gets no such note."""
    bag = tmp_path / "old.mcap"
    write_run(bag, Run(latency_ns=120_000_000_000, movements=(1,)))
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 0, text
    assert "latency is meaningless here: the input stamps were 120.0 s old" in text
    assert "restamp:=true" in text and "slow, not wrong" not in text
    fresh = tmp_path / "fresh.mcap"
    write_run(fresh, Run(movements=(1,)))
    code, text = _check(fresh, reference, capsys=capsys)
    assert code == 0 and "meaningless" not in text, text


def test_latency_gates_only_when_asked(tmp_path, reference, capsys) -> None:
    bag = tmp_path / "slow.mcap"
    write_run(bag, Run(latency_ns=2_500_000, movements=(1,)))
    code, text = _check(bag, reference, "--max-latency-p99-ms", "1", capsys=capsys)
    assert code == 1 and "FAIL: latency p99 2.500 ms > 1 ms (asked-for maximum" in text
    code, text = _check(bag, reference, "--max-latency-p99-ms", "3", capsys=capsys)
    assert code == 0, text
    th = yaml.safe_load(config_file("check.yaml").read_text())
    assert th["latency_p99_ms_max"] is None  # off by default in the shipped file
    th["latency_p99_ms_max"] = 2.0
    th_path = tmp_path / "check.yaml"
    th_path.write_text(yaml.safe_dump(th))
    code, text = _check(bag, reference, "--thresholds", str(th_path), capsys=capsys)
    assert code == 1 and "latency p99 2.500 ms > 2 ms" in text


@pytest.mark.parametrize("run, needle", [
    # no config message: the default model is assumed, and said
    (Run(config=False, movements=(1,)), "warning: no torque_node/config in the bag"),
    # a solid-model run is checked against the solid model, not the default segmented
    (Run(kind="solid", movements=(1,)), "model solid, body size p50 (from torque_node/config)"),
    # no markers (any recording): not refused, analysed against its own filtered positions
    # (offline/score.py; details in test_check_markerless.py)
    (Run(markers=False, movements=(1,)), "no movement markers: one segment"),
], ids=["no-config", "solid-model", "no-markers"])
def test_run_variants_pass_and_say_what_was_assumed(tmp_path, reference, capsys, run, needle) -> None:
    bag = tmp_path / "run.mcap"
    write_run(bag, run)
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 0, text
    assert needle in text


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
    # the movement the cut falls in is flagged, and why
    short = [line for line in text.splitlines() if line.startswith("  ! movement")]
    assert short and "expected samples: the recording ends" in short[0], text
    recovered = tmp_path / "recovered.mcap"
    assert check_bag([str(cut), "--recover", str(recovered)]) == 0
    assert "recovered" in capsys.readouterr().out
    assert _check(recovered, reference, capsys=capsys)[0] == 0


@pytest.mark.parametrize("case", ["empty", "random", "magic_only", "cut_early", "missing"])
def test_corrupt_files_exit_2_with_one_line(tmp_path, good_bag, case, capsys) -> None:
    """In-process (an escaping exception fails the test); the console script as users run it,
    real stderr and exit code: test_faults_files.test_cli_never_prints_a_traceback."""
    path = tmp_path / f"{case}.mcap"
    content = {"empty": b"", "random": os.urandom(10000), "magic_only": b"\x89MCAP0\r\n",
               "cut_early": good_bag.read_bytes()[:3000], "missing": None}[case]
    if content is not None:
        path.write_bytes(content)
    code = check_bag([str(path)])
    out = capsys.readouterr()
    assert code == 2
    assert out.out == ""
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("check_bag: error:") and str(path) in lines[0]
    assert "Traceback" not in out.err


@pytest.mark.parametrize(("run", "needle"), [
    (Run(torques=False, movements=(1,)), "no joint_torques"),
])
def test_foreign_bags_exit_2(tmp_path, reference, run, needle, capsys) -> None:
    bag = tmp_path / "foreign.mcap"
    write_run(bag, run)
    code, text = _check(bag, reference, capsys=capsys)
    assert code == 2
    assert needle in text and len(text.strip().splitlines()) == 1


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
    assert len(text.strip().splitlines()) == 1 and "does not decode as JointState" in text


def test_json_report_keys_are_documented(good_bag, reference, tmp_path, capsys) -> None:
    """Every key the --json report writes is named in check_bag's help (its docstring)."""
    import forearm_dynamics.cli.check_bag as cli

    out_json = tmp_path / "report.json"
    _check(good_bag, reference, "--json", str(out_json), capsys=capsys)
    report = json.loads(out_json.read_text())
    doc = cli.__doc__.split("The --json report", 1)[1]
    words = set(doc.replace(",", " ").replace("{", " ").replace("}", " ").replace("(", " ").split())
    keys = set(report) | set(report["bag"]) | set(report["model"]) | set(report["delivery"]) \
        | set(report["machine"]) | set(report["movements"][0]) | set(report["delivery"]["latency_ms"])
    assert sorted(keys - words) == []
SENSOR = {"noise_deg": 0.5, "publish_velocity": False, "jitter_ms": 0.0, "drop_fraction": 0.0,
          "seed": 3}


def test_noisy_sensor_input_is_scored_against_the_noiseless_truth(tmp_path, reference, capsys) -> None:
    """Noisy positions within the stated noise pass the state check; torques 5 % off (an
    estimator on noisy input) are reported but not gated, and the report says why."""
    bag = tmp_path / "noisy.mcap"
    write_run(bag, Run(sensor=SENSOR, offset={WRIST: 0.05}))
    code, out = _check(bag, reference, capsys=capsys)
    assert code == 0, out
    assert "simulated sensor (Gaussian noise 0.5 deg on positions, positions only" in out
    assert "noiseless analytic truth" in out and "reported, not gated" in out
    # the same torques from exact input: the gate applies
    bag = tmp_path / "exact.mcap"
    write_run(bag, Run(offset={WRIST: 0.05}))
    code, out = _check(bag, reference, capsys=capsys)
    assert code == 1 and "pipeline NRMSE" in out, out


def test_positions_beyond_the_stated_noise_fail(tmp_path, reference, capsys) -> None:
    bag = tmp_path / "wrong.mcap"
    write_run(bag, Run(sensor=SENSOR, position_offset=10 * np.radians(0.5)))
    code, out = _check(bag, reference, capsys=capsys)
    assert code == 1 and "stated noise" in out and "publisher side" in out, out
