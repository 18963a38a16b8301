"""Disk faults for bag_recorder (a real process on loopback DDS) and BagWriter: output
directory missing or not a directory, read-only, disk full at start, mid-recording and at
close, file size limit. Expected: one clear error line, a bounded exit (2 for a refused
output, 1 for a failed write; never a traceback, never a retry loop), and whatever was
already written stays readable (and `check_bag --recover` makes it a complete bag that
rosbags reads).

Mechanisms (each test prints the one it used):
- read-only: a tmpfs remounted read-only (needs mount, i.e. root here); otherwise chmod 555
  (works when not root); otherwise (root without mount) a path under /proc.
- disk full: a 2 MiB tmpfs, pre-filled (needs mount); /dev/full for the in-process writer.
- file size limit: RLIMIT_FSIZE with SIGXFSZ ignored (works everywhere): writes fail EFBIG,
  the same path as a full disk, so the mid-recording case is covered without mount too.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rosproc
from faultkit import (
    POSTURE,
    Procs,
    joint_series,
    joint_state,
    private_domain,
    start_feeder,
)
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader

from forearm_dynamics.bag import BagWriter, open_bag, recover
from forearm_dynamics.errors import BagWriteError

pytestmark = [pytest.mark.faults, pytest.mark.ros]


def _mount(target: Path, *options: str) -> bool:
    try:
        res = subprocess.run(["mount", "-t", "tmpfs", "-o", ",".join(options), "tmpfs", str(target)],
                             capture_output=True, timeout=10, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return res.returncode == 0


def _umount(target: Path) -> None:
    subprocess.run(["umount", "-l", str(target)], capture_output=True, timeout=10, check=False)


@pytest.fixture
def small_disk(tmp_path):
    """A 2 MiB tmpfs, or None when this machine cannot mount one."""
    target = tmp_path / "small"
    target.mkdir()
    if not _mount(target, "size=2m", "mode=0755"):
        yield None
        return
    try:
        yield target
    finally:
        _umount(target)


@pytest.fixture
def read_only_dir(tmp_path):
    """(directory, mechanism) where creating a file fails, as described in the module doc."""
    target = tmp_path / "ro"
    target.mkdir()
    if _mount(target, "size=1m", "ro"):
        try:
            yield target, "tmpfs mounted read-only"
        finally:
            _umount(target)
    elif os.geteuid() != 0:
        target.chmod(0o555)
        yield target, "chmod 555 (not root)"
        target.chmod(0o755)
    else:
        yield Path("/proc"), "/proc (root without mount: no other unwritable directory)"


def fill(disk: Path, leave: int) -> None:
    """Fill the file system of `disk` until about `leave` bytes are free."""
    st = os.statvfs(disk)
    free = st.f_bavail * st.f_frsize
    with open(disk / "filler", "wb") as fh:
        fh.write(b"\0" * max(free - leave, 0))


def one_error_line(output: str) -> str:
    lines = [ln for ln in output.splitlines() if "[ERROR]" in ln]
    assert len(lines) == 1, output
    assert "Traceback" not in output
    return lines[0]


# -- refused at start ------------------------------------------------------------------------
def test_output_under_a_file_exits_2(tmp_path) -> None:
    (tmp_path / "plain.txt").write_text("not a directory")
    out = tmp_path / "plain.txt" / "run.mcap"
    rec = rosproc.start("bag_recorder", "-p", f"output:={out}", domain=private_domain())
    assert rec.wait(30) == 2
    line = one_error_line(rec.output())
    assert "invalid parameter 'output'" in line and "Not a directory" in line, line


def test_read_only_directory_exits_2(read_only_dir, tmp_path) -> None:
    directory, mechanism = read_only_dir
    out = directory / "run.mcap"
    rec = rosproc.start("bag_recorder", "-p", f"output:={out}", domain=private_domain())
    assert rec.wait(30) == 2
    line = one_error_line(rec.output())
    assert "invalid parameter 'output'" in line and str(out) in line, line
    assert not out.exists()
    # check_bag --recover into it: the same kind of refusal
    src = tmp_path / "src.mcap"
    with BagWriter(src) as w:
        ch = w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        w.write(ch, serialize_message(joint_state(10**18)), 1)
    res = subprocess.run([str(rosproc.BIN / "check_bag"), str(src), "--recover", str(out)],
                         env=rosproc.ros_env(), capture_output=True, text=True, timeout=60,
                         check=False)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    print(f"read-only ({mechanism}): {line.split(']: ')[-1]}")


def test_disk_full_at_start_exits_2_and_leaves_no_file(small_disk) -> None:
    if small_disk is None:
        pytest.skip("mount -t tmpfs is not permitted here (disk full at start is also covered "
                    "in-process with /dev/full)")
    fill(small_disk, 0)
    out = small_disk / "run.mcap"
    rec = rosproc.start("bag_recorder", "-p", f"output:={out}", domain=private_domain())
    assert rec.wait(30) == 2
    line = one_error_line(rec.output())
    assert "No space left on device" in line and str(out) in line, line
    assert not out.exists()


def test_writer_on_dev_full() -> None:
    """In-process, no mount needed: the header cannot be written -> one clear error."""
    with pytest.raises(BagWriteError, match="cannot write to /dev/full: No space left on device"):
        BagWriter("/dev/full", overwrite=True)


# -- failing while recording ------------------------------------------------------------------
#: Runs argv[1:] with a file size limit of argv[1] bytes; SIGXFSZ ignored, so writes beyond
#: it fail with EFBIG (as a full disk fails with ENOSPC) instead of killing the process.
FSIZE_WRAPPER = (
    "import os, resource, signal, sys\n"
    "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
    "n = int(sys.argv[1])\n"
    "resource.setrlimit(resource.RLIMIT_FSIZE, (n, n))\n"
    "os.execv(sys.argv[2], sys.argv[2:])\n"
)


def _record_until_failure(procs: Procs, tmp: Path, out: Path, file_limit: int | None = None):
    """Feeder (1 kHz, 4 s) -> bag_recorder writing to `out` until a write fails."""
    domain = private_domain()
    env = rosproc.ros_env(domain)
    args = [str(rosproc.BIN / "bag_recorder"), "--ros-args", "-p", f"output:={out}",
            "-p", "compression:=none", "-p", "chunk_size:=65536", "-p", "flush_period:=0.2"]
    if file_limit is not None:
        args = [sys.executable, "-c", FSIZE_WRAPPER, str(file_limit), *args]
    rec = procs.add(rosproc.NodeProcess("recorder", args, env, tmp))
    feeder, stamps_file, flog = start_feeder(procs, tmp, domain, count=4000, rate_hz=1000.0)
    code = rec.wait(timeout=60)
    feeder.wait(timeout=60)
    assert feeder.returncode == 0, flog.read_text()
    sent = np.array([int(s) for s in stamps_file.read_text().split()])
    return code, rec.text(), sent


def _check_partial(out: Path, output: str, sent: np.ndarray, tmp: Path) -> str:
    """The error names what was kept; the file holds exactly that, readable, recoverable."""
    line = one_error_line(output)
    kept = int(re.search(r"completed chunks keep (\d+) messages", line).group(1))
    bag = open_bag(out)
    assert not bag.info.complete and bag.info.message_count == kept > 0, (bag.info, line)
    # the partly written record was cut off: every byte left is a complete record
    assert bag.info.good_bytes == out.stat().st_size, bag.info.problem
    stamps = joint_series(bag, "joint_states")["stamp"]
    i = int(np.searchsorted(sent, stamps[0]))
    np.testing.assert_array_equal(stamps, sent[i:i + len(stamps)])  # an unbroken run
    fixed = tmp / "recovered.mcap"
    assert recover(out, fixed).messages == kept
    with Reader(fixed) as r:
        assert sum(c.msgcount for c in r.connections) == kept
        assert sum(1 for _ in r.messages()) == kept
    return line


def test_disk_full_mid_recording(small_disk, procs, tmp_path) -> None:
    if small_disk is None:
        pytest.skip("mount -t tmpfs is not permitted here; the mid-recording write failure is "
                    "covered by test_file_size_limit_mid_recording")
    fill(small_disk, 600_000)
    out = small_disk / "run.mcap"
    code, output, sent = _record_until_failure(procs, tmp_path, out)
    assert code == 1, output  # stopped once, did not retry
    line = _check_partial(out, output, sent, tmp_path)
    assert "No space left on device" in line
    print(f"disk full (2 MiB tmpfs): exit 1; {line.split(']: ')[-1]}; {len(sent)} sent")


def test_file_size_limit_mid_recording(procs, tmp_path) -> None:
    out = tmp_path / "run.mcap"
    code, output, sent = _record_until_failure(procs, tmp_path, out, file_limit=400_000)
    assert code == 1, output
    line = _check_partial(out, output, sent, tmp_path)
    assert "File too large" in line
    print(f"file size limit (RLIMIT_FSIZE 400 kB): exit 1; {line.split(']: ')[-1]}")


def test_disk_full_at_close(small_disk, tmp_path) -> None:
    """In-process: the last chunk and the summary do not fit. The error names what the
    completed chunks keep, and exactly that is readable and recoverable."""
    if small_disk is None:
        pytest.skip("mount -t tmpfs is not permitted here")
    out = small_disk / "run.mcap"
    w = BagWriter(out, compression="none", chunk_size=200_000, flush_period_s=3600)
    ch = w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    rng = np.random.default_rng(0)
    n = 0
    while w.durable_count == 0 or n % 700:  # at least one chunk on disk, a second one open
        w.write(ch, serialize_message(joint_state(10**18 + n * 10**6, POSTURE + rng.normal(0, 1, 20))),
                10**18 + n)
        n += 1
    fill(small_disk, 0)
    with pytest.raises(BagWriteError) as err:
        w.close()
    kept = int(re.search(r"completed chunks keep (\d+) messages", str(err.value)).group(1))
    assert kept == w.durable_count < n
    assert "No space left on device" in str(err.value)
    (small_disk / "filler").unlink()
    bag = open_bag(out)
    assert bag.info.message_count == kept and not bag.info.complete
    assert recover(out, tmp_path / "fixed.mcap").messages == kept
    print(f"disk full at close: {n} written, {kept} in completed chunks kept, error: {err.value}")



def test_write_failure_keeps_what_it_says(tmp_path, monkeypatch) -> None:
    """In-process, at chosen failure points: the file ends after byte `limit` (as
    RLIMIT_FSIZE or a full disk cut it). The error's "completed chunks keep N" is exactly
    what a reader finds in the file wherever the cut falls: inside a Chunk record, or just
    after one, in the message index records mcap writes next (the case that made the
    recorder report 378 messages kept while the file held 456)."""
    import errno

    from mcap.opcode import Opcode

    import forearm_dynamics.bag.writer as writer_module

    real_write = os.write
    msgs = [serialize_message(joint_state(10**18 + n * 10**6, POSTURE)) for n in range(150)]
    calls: list[tuple[int, int, int]] = []  # (offset, length, opcode) of each write call

    def logged_write(fd, data):
        n = real_write(fd, data)
        calls.append((sum(c[1] for c in calls), n, data[0] if n else -1))
        return n

    def record(path, write) -> BagWriter:
        monkeypatch.setattr(writer_module.os, "write", write)
        try:
            w = BagWriter(path, compression="none", chunk_size=4096, flush_period_s=3600)
            ch = w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
            for n, m in enumerate(msgs):
                w.write(ch, m, 10**18 + n)
            w.close()
        finally:
            monkeypatch.setattr(writer_module.os, "write", real_write)
        return w

    record(tmp_path / "probe.mcap", logged_write)
    chunks = [(off, n) for off, n, op in calls if op == Opcode.CHUNK]
    assert len(chunks) >= 4, calls
    limits = {"inside a chunk": [off + n // 2 for off, n in chunks[1:4]],
              "after a whole chunk": [off + n for off, n in chunks[1:4]]}
    for where, cuts in limits.items():
        for limit in cuts:
            out = tmp_path / f"cut_{limit}.mcap"
            written = [0]

            def limited_write(fd, data, _written=written, _limit=limit):
                room = _limit - _written[0]
                if room <= 0:
                    raise OSError(errno.EFBIG, "File too large")
                n = real_write(fd, bytes(data[:room]))
                _written[0] += n
                return n

            with pytest.raises(BagWriteError) as err:
                record(out, limited_write)
            kept = int(re.search(r"completed chunks keep (\d+) messages", str(err.value)).group(1))
            bag = open_bag(out)
            assert bag.info.message_count == kept > 0, (where, limit, str(err.value))
            assert bag.info.good_bytes == out.stat().st_size, (where, limit, bag.info.problem)
            assert recover(out, tmp_path / f"fixed_{limit}.mcap").messages == kept
