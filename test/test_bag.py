"""The bag writer/reader against an independent reader (rosbags), cut files and bad files."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from std_msgs.msg import String
from support.jointstate import joint_state_bytes

from forearm_dynamics import JOINT_NAMES
from forearm_dynamics.bag import BagWriter, TopicQos, open_bag, recover
from forearm_dynamics.bag.schemas import DELIMITER, message_definition
from forearm_dynamics.errors import (
    BagEmpty,
    BagError,
    BagNoData,
    BagWriteError,
    NotMcap,
    OutputDirMissing,
)
from forearm_dynamics.exit_codes import USAGE

pytestmark = pytest.mark.unit

T0 = 1_700_000_000_000_000_000
N_STATES = 6000


def joint_state(k: int) -> bytes:
    # effort filled: Fast-CDR (rclpy) pads an empty float64[] with 4 bytes that rosbags'
    # strict size check rejects when deserialising (the bag itself is fine either way).
    return joint_state_bytes(T0 + k * 1_000_000, [0.001 * k + j for j in range(20)],
                             [-0.5 * j for j in range(20)], [0.25 * j for j in range(20)],
                             frame_id="")


def diagnostics(k: int) -> bytes:
    status = DiagnosticStatus(level=DiagnosticStatus.OK, name="torque_node: pipeline",
                              values=[KeyValue(key="received", value=str(k))])
    return serialize_message(DiagnosticArray(status=[status]))


@pytest.fixture(scope="module")
def sample_bag(tmp_path_factory) -> tuple[Path, list[tuple[str, bytes]]]:
    """~6 MB uncompressed: several size-closed chunks; returns (path, [(topic, payload)])."""
    path = tmp_path_factory.mktemp("bag") / "sample.mcap"
    written = []
    with BagWriter(path, flush_period_s=3600) as w:
        js = w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        cfg = w.add_topic("/torque_node/config", "std_msgs/msg/String",
                          TopicQos(depth=1, durability="transient_local"))
        diag = w.add_topic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
        data = serialize_message(String(data='{"model": "segmented"}'))
        w.write(cfg, data, T0)
        written.append(("/torque_node/config", data))
        for k in range(N_STATES):
            data = joint_state(k)
            w.write(js, data, T0 + k * 1_000_000 + 300_000)
            written.append(("/joint_states", data))
            if k % 1000 == 0:
                data = diagnostics(k)
                w.write(diag, data, T0 + k * 1_000_000 + 400_000)
                written.append(("/diagnostics", data))
    return path, written


def test_rosbags_reads_bare_mcap(sample_bag) -> None:
    path, written = sample_bag
    with Reader(path) as r:
        types = {c.topic: c.msgtype for c in r.connections}
        counts = {c.topic: c.msgcount for c in r.connections}
        payloads = [(c.topic, bytes(raw)) for c, _t, raw in r.messages()]
        qos = {c.topic: c.ext.offered_qos_profiles[0] for c in r.connections}
    assert types == {"/joint_states": "sensor_msgs/msg/JointState",
                     "/torque_node/config": "std_msgs/msg/String",
                     "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}
    assert counts == {"/joint_states": N_STATES, "/torque_node/config": 1, "/diagnostics": 6}
    assert payloads == written
    assert qos["/torque_node/config"].durability.name == "TRANSIENT_LOCAL"
    assert qos["/joint_states"].depth == 1000


def test_rosbags_decodes_with_the_stored_schemas(sample_bag) -> None:
    """AnyReader builds its types from our schema text alone: the definitions are complete."""
    path, _ = sample_bag
    with AnyReader([path]) as r:
        seen = {}
        for conn, _t, raw in r.messages():
            seen.setdefault(conn.topic, r.deserialize(raw, conn.msgtype))
    js = seen["/joint_states"]
    assert list(js.name) == list(JOINT_NAMES) and js.position[3] == pytest.approx(3.0)
    assert js.header.stamp.sec == T0 // 10**9
    assert seen["/diagnostics"].status[0].values[0].key == "received"
    assert seen["/torque_node/config"].data == '{"model": "segmented"}'


def test_our_reader_matches(sample_bag) -> None:
    path, written = sample_bag
    bag = open_bag(path)
    assert bag.info.complete and bag.info.problem is None
    assert bag.info.topic_counts() == {"/joint_states": N_STATES, "/torque_node/config": 1,
                                       "/diagnostics": 6}
    assert [(c.topic, bytes(m.data)) for c, m in bag.messages()] == written
    assert bag.info.find_topic("joint_states").topic == "/joint_states"


def test_rosbag2_format_details(sample_bag) -> None:
    """What rosbag2's MCAP plugin reads: profile, schema text, channel and bag metadata."""
    path, _ = sample_bag
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        header, summary = reader.get_header(), reader.get_summary()
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert header.profile == "ros2" and "forearm_dynamics" in header.library
    schemas = {s.name: s for s in summary.schemas.values()}
    js = schemas["sensor_msgs/msg/JointState"]
    assert js.encoding == "ros2msg"
    text = js.data.decode()
    assert text == message_definition("sensor_msgs/msg/JointState")
    assert "\n" + DELIMITER + "MSG: std_msgs/Header\n" in text
    assert "\n" + DELIMITER + "MSG: builtin_interfaces/Time\n" in text
    assert "MSG: diagnostic_msgs/KeyValue" in schemas["diagnostic_msgs/msg/DiagnosticArray"].data.decode()
    for ch in summary.channels.values():
        assert ch.message_encoding == "cdr"
        assert ch.metadata["topic_type_hash"].startswith("RIHS01_")
        qos = yaml.safe_load(ch.metadata["offered_qos_profiles"])
        assert qos[0]["reliability"] == "reliable" and qos[0]["history"] == "keep_last"
    info = yaml.safe_load(meta["rosbag2"]["serialized_metadata"])
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["message_count"] == N_STATES + 7
    assert summary.statistics.message_count == N_STATES + 7
    assert len(summary.chunk_indexes) >= 4
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
    # chunks close at the size limit: none is much larger than 1 MiB uncompressed
    assert max(c.uncompressed_size for c in summary.chunk_indexes) < 1024 * 1024 + 4096


def test_chunks_close_on_wall_time(tmp_path) -> None:
    """A slow stream still gets its chunks closed every flush period (SIGKILL safety)."""
    import time

    path = tmp_path / "slow.mcap"
    w = BagWriter(path, flush_period_s=0.05)
    js = w.add_topic("joint_states", "sensor_msgs/msg/JointState")
    for k in range(8):
        w.write(js, joint_state(k), T0 + k)
        time.sleep(0.06)
    w.abort()  # as if killed: no summary
    bag = open_bag(path)
    assert not bag.info.complete
    assert bag.info.chunk_count >= 6
    assert bag.info.message_count >= 7


def _complete_chunk_messages(path: Path, cut: int) -> int:
    """Messages inside the chunks that end before byte `cut` (from the intact file's index)."""
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
        total = 0
        for ci in summary.chunk_indexes:
            if ci.chunk_start_offset + ci.chunk_length <= cut:
                fh.seek(ci.chunk_start_offset + 9)
                chunk = Chunk.read(ReadDataStream(fh))
                total += sum(isinstance(r, Message) for r in breakup_chunk(chunk))
    return total


@pytest.mark.parametrize("fraction", [0.2, 0.55, 0.9, 0.999])
def test_truncated_bag_is_recovered(sample_bag, tmp_path, fraction) -> None:
    path, written = sample_bag
    data = path.read_bytes()
    cut = int(len(data) * fraction)
    cut_path = tmp_path / "cut.mcap"
    cut_path.write_bytes(data[:cut])
    expected = _complete_chunk_messages(path, cut)
    assert expected > 0
    bag = open_bag(cut_path)
    assert not bag.info.complete and "ends inside a record" in bag.info.problem
    assert bag.info.message_count == expected
    got = [(c.topic, bytes(m.data)) for c, m in bag.messages()]
    assert got == written[:expected]

    out = tmp_path / "recovered.mcap"
    res = recover(cut_path, out)
    assert res.messages == expected and not res.source_complete
    assert open_bag(out).info.complete
    with Reader(out) as r:  # the independent reader accepts the rewritten file
        assert sum(c.msgcount for c in r.connections) == expected
        assert [(c.topic, bytes(raw)) for c, _t, raw in r.messages()] == written[:expected]


def test_damaged_chunk(sample_bag, tmp_path) -> None:
    """Bytes flipped inside a chunk: reading says so in one line; recover keeps what precedes."""
    path, _ = sample_bag
    with open(path, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    data = bytearray(path.read_bytes())
    target = chunks[2].chunk_start_offset + chunks[2].chunk_length // 2
    data[target:target + 64] = os.urandom(64)
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(BagError, match="damaged") as exc:
        for _ in open_bag(bad).messages():
            pass
    assert "\n" not in str(exc.value)
    res = recover(bad, tmp_path / "ok.mcap")
    assert res.messages == _complete_chunk_messages(path, chunks[2].chunk_start_offset) > 0
    assert "damaged" in res.problem


@pytest.mark.parametrize(("content", "kind"), [
    (b"", BagEmpty),
    (os.urandom(4096), NotMcap),
    (b"\x89MCAP0\r\n" + b"\x01\xff\xff", BagNoData),
])
def test_bad_files(tmp_path, content, kind) -> None:
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    with pytest.raises(BagError) as exc:
        open_bag(path)
    assert type(exc.value) is kind and kind.exit_code == USAGE
    assert "\n" not in str(exc.value) and str(path) in str(exc.value)


def test_missing_file(tmp_path) -> None:
    with pytest.raises(BagError, match="no such file"):
        open_bag(tmp_path / "nope.mcap")


def test_writer_refuses_overwrite_and_missing_dir(tmp_path) -> None:
    existing = tmp_path / "x.mcap"
    existing.write_bytes(b"keep me")
    with pytest.raises(BagWriteError, match="exists already"):
        BagWriter(existing)
    assert existing.read_bytes() == b"keep me"
    with pytest.raises(BagWriteError, match="does not exist") as exc:
        BagWriter(tmp_path / "no" / "such" / "dir.mcap")
    assert isinstance(exc.value, OutputDirMissing) and exc.value.exit_code == USAGE


def test_disk_full_is_a_clear_error() -> None:
    """/dev/full: every write fails with ENOSPC, as on a full disk."""
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")
    with pytest.raises(BagWriteError, match="No space left on device"):
        BagWriter("/dev/full", overwrite=True)


def test_write_failure_midway(tmp_path, monkeypatch) -> None:
    """A failure at a chunk boundary: one error, later writes fail fast, the file stays readable."""
    path = tmp_path / "full.mcap"
    w = BagWriter(path, flush_period_s=3600, chunk_size=64 * 1024)
    js = w.add_topic("joint_states", "sensor_msgs/msg/JointState")
    for k in range(200):
        w.write(js, joint_state(k), T0 + k)
    w.flush()
    real_write = os.write

    def full(fd, data):
        if fd == w._fd:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", full)
    with pytest.raises(BagWriteError, match="No space left on device"):
        for k in range(200, 2000):
            w.write(js, joint_state(k), T0 + k)
    with pytest.raises(BagWriteError):
        w.write(js, joint_state(0), T0)
    with pytest.raises(BagWriteError):
        w.close()
    monkeypatch.undo()
    assert open_bag(path).info.message_count == 200
