"""Corrupt and foreign files for check_bag: exit 2 with one clear line (never a traceback)
when nothing can be analysed; a damaged file that still holds complete chunks is analysed
with a warning. test_check_bag.py already covers a zero-byte file, 10 kB of random bytes,
the magic alone, a 3000-byte cut, a missing file and (in-process) no joint_torques / no
markers / garbage payloads; this file sweeps truncation points and bit flips, and covers
the remaining foreign bags and every `--recover` refusal.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosproc import ros_env
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from test_check_bag import Run, write_run

from forearm_dynamics.bag import BagWriter, open_bag
from forearm_dynamics.cli.check_bag import main as check_bag

pytestmark = [pytest.mark.faults, pytest.mark.cli]

T0 = 1_750_000_000_000_000_000


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("files") / "good.mcap"
    write_run(path, Run(movements=(1, 28)))
    return path


def run_main(*args: str) -> tuple[int, str, str]:
    """check_bag's main in-process: (exit code, stdout, stderr); an escaping exception fails."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = check_bag(list(args))
    return code, out.getvalue(), err.getvalue()


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "forearm_dynamics.cli.check_bag", *args],
                          check=False, capture_output=True, text=True, env=ros_env(), timeout=120)


def assert_one_line_refusal(code: int, out: str, err: str, path: Path | str) -> str:
    assert code == 2, out + err
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("check_bag: error:"), err
    assert str(path) in lines[0] and "Traceback" not in err
    return lines[0]


def record_offsets(data: bytes) -> list[int]:
    """Start offsets of the MCAP records (opcode, u64 length), after the magic."""
    pos, offsets = 8, []
    while pos + 9 <= len(data):
        offsets.append(pos)
        length = struct.unpack_from("<Q", data, pos + 1)[0]
        pos += 9 + length
    return offsets


# -- damaged copies of a good bag --------------------------------------------------------------
def test_truncated_anywhere(good, tmp_path) -> None:
    """Cut at a record boundary, one byte after it and in the middle of a record (every
    record up to the first chunks, then spread over the file, and the footer): either
    refused in one line (nothing complete to analyse) or analysed with a warning, and the
    number of messages analysed never decreases as the cut moves on."""
    data = good.read_bytes()
    offsets = record_offsets(data)
    ends = [*offsets[1:], len(data)]
    chosen = [*range(min(8, len(offsets))), *range(8, len(offsets), max(1, len(offsets) // 10))]
    cuts = sorted({c for i in chosen for c in (offsets[i], offsets[i] + 1, (offsets[i] + ends[i]) // 2)}
                  | {len(data) - 1, len(data) - 8})
    path = tmp_path / "cut.mcap"
    refused, analysed, last = 0, 0, -1
    for cut in cuts:
        path.write_bytes(data[:cut])
        code, out, err = run_main(str(path), "--reference", str(tmp_path / "none.npz"))
        if code == 2:
            assert_one_line_refusal(code, out, err, path)
            refused += 1
            assert analysed == 0 or "damaged" in err or "no_data" in err, (cut, err)
            continue
        assert code in (0, 1), (cut, out, err)
        assert "warning: bag is truncated" in out or cut >= len(data) - 8, (cut, out)
        n = int(out.split(": ", 1)[1].split(" messages")[0])
        assert n >= last, (cut, n, last)
        last = n
        analysed += 1
    assert refused and analysed
    print(f"{len(cuts)} cut points: {refused} refused in one line, {analysed} analysed "
          f"(up to {last} messages)")


def test_bit_flips(good, tmp_path) -> None:
    seed = 20251123
    rng = random.Random(seed)
    data = good.read_bytes()
    path = tmp_path / "flipped.mcap"
    outcomes = {0: 0, 1: 0, 2: 0}
    for _ in range(40):
        b = bytearray(data)
        b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        path.write_bytes(bytes(b))
        code, out, err = run_main(str(path), "--reference", str(tmp_path / "none.npz"))
        assert code in outcomes, (code, out, err)
        if code == 2:
            assert_one_line_refusal(code, out, err, path)
        outcomes[code] += 1
    assert outcomes[2]  # a flip inside a chunk fails its CRC: refused, never misread
    print(f"40 single-bit flips (seed {seed}): exit codes {outcomes}")


# -- files that are no run of ours --------------------------------------------------------------
def _bag(path: Path, build) -> Path:
    with BagWriter(path) as w:
        build(w)
    return path


def _other_topics(w: BagWriter) -> None:
    chat = w.add_topic("/chatter", "std_msgs/msg/String")
    imu = w.add_topic("/wrist_imu", "sensor_msgs/msg/JointState")
    for k in range(50):
        w.write(chat, serialize_message(String(data=f"hello {k}")), T0 + k)
        w.write(imu, serialize_message(JointState(name=["x"], position=[0.1])), T0 + k)


def _torques(w: BagWriter, names=None, marker: str | None = '{"id": 1, "t0_ns": %d}') -> None:
    from faultkit import joint_state

    from forearm_dynamics import JOINT_NAMES

    tq = w.add_topic("/joint_torques", "sensor_msgs/msg/JointState")
    mv = w.add_topic("/movement", "std_msgs/msg/String")
    if marker is not None:
        w.write(mv, serialize_message(String(data=marker % T0 if "%d" in marker else marker)), T0)
    for k in range(300):
        m = joint_state(T0 + k * 1_000_000, names=names or JOINT_NAMES,
                        q=[0.1] * len(names or JOINT_NAMES), effort=[0.0] * len(names or JOINT_NAMES))
        w.write(tq, serialize_message(m), T0 + k * 1_000_000 + 300_000)


def _torques_as_strings(w: BagWriter) -> None:
    tq = w.add_topic("/joint_torques", "std_msgs/msg/String")
    mv = w.add_topic("/movement", "std_msgs/msg/String")
    w.write(mv, serialize_message(String(data=json.dumps({"id": 1, "t0_ns": T0}))), T0)
    for k in range(20):
        w.write(tq, serialize_message(String(data="1.0, 2.0")), T0 + k)


FOREIGN = {
    "other_topics": (_other_topics, "no joint_torques topic (topics: /chatter, /wrist_imu)"),
    "no_markers": (lambda w: _torques(w, marker=None), "no movement markers"),
    "markers_not_json": (lambda w: _torques(w, marker="movement one"), "no movement markers"),
    "unknown_movement": (lambda w: _torques(w, marker='{"id": 99, "t0_ns": %d}'),
                         "no movement marker names a known movement"),
    "other_robot_joints": (lambda w: _torques(w, names=["hip", "knee", "ankle"]),
                           "no joint_torques message carries an effort for every joint"),
    "torques_of_another_type": (_torques_as_strings, "does not decode as JointState"),
    "no_torque_messages": (lambda w: (w.add_topic("/joint_torques", "sensor_msgs/msg/JointState"),
                                      _other_topics(w)), "holds no message"),
}


@pytest.mark.parametrize("case", list(FOREIGN))
def test_foreign_bag_is_refused_in_one_line(tmp_path, case) -> None:
    build, needle = FOREIGN[case]
    path = _bag(tmp_path / f"{case}.mcap", build)
    code, out, err = run_main(str(path))
    line = assert_one_line_refusal(code, out, err, path)
    assert needle in line, line


@pytest.mark.parametrize("case", ["random_1MB", "magic_then_random", "directory", "other_topics"])
def test_cli_never_prints_a_traceback(tmp_path, case) -> None:
    """The console entry point as users run it: real stderr, real exit code."""
    path = tmp_path / f"{case}.mcap"
    if case == "random_1MB":
        path.write_bytes(os.urandom(1 << 20))
    elif case == "magic_then_random":
        path.write_bytes(b"\x89MCAP0\r\n" + os.urandom(5000))
    elif case == "directory":
        path.mkdir()
    else:
        _bag(path, _other_topics)
    res = cli(str(path))
    assert_one_line_refusal(res.returncode, res.stdout, res.stderr, path)


# -- check_bag --recover ---------------------------------------------------------------------------
def test_recover_rewrites_a_truncated_bag(good, tmp_path) -> None:
    data = good.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    kept = open_bag(cut).info
    fixed = tmp_path / "fixed.mcap"
    code, out, err = run_main(str(cut), "--recover", str(fixed))
    assert code == 0 and f"recovered {kept.message_count} messages" in out, out + err
    assert open_bag(fixed).info.complete
    src = {(ch.topic, m.log_time, bytes(m.data)) for ch, m in open_bag(cut).messages()}
    with AnyReader([fixed]) as reader:  # the independent reader
        got = {(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()}
        types = {c.topic: c.msgtype for c in reader.connections}
    assert got == src and len(got) == kept.message_count
    assert types["/joint_torques"] == "sensor_msgs/msg/JointState"
    assert run_main(str(fixed))[0] in (0, 1)  # and check_bag analyses it


def _recover_case(case: str, tmp: Path, good: Path) -> tuple[Path, Path]:
    src, dst = good, tmp / "out.mcap"
    if case == "input_empty":
        src = tmp / "empty.mcap"
        src.write_bytes(b"")
    elif case == "input_random":
        src = tmp / "random.mcap"
        src.write_bytes(os.urandom(4096))
    elif case == "input_missing":
        src = tmp / "missing.mcap"
    elif case == "input_header_only":
        src = tmp / "header.mcap"
        src.write_bytes(good.read_bytes()[:record_offsets(good.read_bytes())[1]])
    elif case == "output_exists":
        dst.write_bytes(b"keep me")
    elif case == "output_dir_missing":
        dst = tmp / "no" / "such" / "out.mcap"
    elif case == "output_is_input":
        dst = good
    elif case == "output_is_a_directory":
        dst = tmp
    return src, dst


@pytest.mark.parametrize("case", ["input_empty", "input_random", "input_missing", "input_header_only",
                                  "output_exists", "output_dir_missing", "output_is_input",
                                  "output_is_a_directory"])
def test_recover_refusals(good, tmp_path, case) -> None:
    before = good.read_bytes()
    src, dst = _recover_case(case, tmp_path, good)
    code, out, err = run_main(str(src), "--recover", str(dst))
    line = assert_one_line_refusal(code, out, err, src if case.startswith("input") else dst)
    assert good.read_bytes() == before
    if case == "output_exists":
        assert dst.read_bytes() == b"keep me"
    print(line)
