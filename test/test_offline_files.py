"""Nothing lost offline (issue 30): a bag_torques output cut at random points keeps all but
its last second (read by the package's reader; what it recovers read back by rosbags, the
independent reader, and equal to rosbags' reading of the intact file); bag_export says
"truncated" and never writes inf (OpenSim reads its .sto); check_bag picks a cutoff a
10 Hz bag can use, or takes --cutoff, and says which."""

from __future__ import annotations

import csv
import subprocess

import numpy as np
import opensim as osim
import pytest
from bagkit import MS, write_stream_bag
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosproc import BIN, ros_env

from forearm_dynamics import JOINT_NAMES
from forearm_dynamics.bag import open_bag
from forearm_dynamics.bag.recover import recover
from forearm_dynamics.codec.jointstate import read_joint_series

pytestmark = pytest.mark.cli

N = 1500  # 100 Hz: 15 s
SPAN_NS = 1_000_000_000  # "all but its last second"


def run(tool: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / tool), *map(str, args)], env=ros_env(), capture_output=True,
                          text=True, timeout=600, check=False)


def rosbags_torques(path) -> dict[int, tuple[int, np.ndarray]]:
    """{stamp: (log time, effort)} of /joint_torques, read with rosbags."""
    out = {}
    with AnyReader([path]) as r:
        conns = [c for c in r.connections if c.topic == "/joint_torques"]
        for c, log, raw in r.messages(connections=conns):
            m = r.deserialize(raw, c.msgtype)
            out[m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec] = (log, np.array(m.effort))
    return out


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("offline_files")
    src, out = d / "in.mcap", d / "out.mcap"
    write_stream_bag(src, N, period_ns=10 * MS)
    r = run("bag_torques", src, out)
    assert r.returncode == 0, r.stderr
    return d, out, rosbags_torques(out)


def test_chunks_hold_half_a_second(made) -> None:
    _d, out, _ref = made
    with open(out, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    spans = [c.message_end_time - c.message_start_time for c in chunks]
    print(f"{out.stat().st_size} bytes, {len(chunks)} chunks, log-time span per chunk max "
          f"{max(spans) / 1e9:.3f} s")
    assert len(chunks) >= 25 and max(spans) < 500 * MS, (len(chunks), max(spans))


def test_a_cut_file_keeps_all_but_its_last_second(made, tmp_path) -> None:
    """8 cuts at seeded random byte offsets: the package's reader reads each cut file to
    its last complete chunk; the torques it finds are the intact file's (as rosbags reads
    that), a prefix in stamp order, and reach within 1 s of the newest message that began
    before the cut; recover() writes them to a file rosbags reads with the same values."""
    _d, out, ref = made
    data = out.read_bytes()
    with open(out, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    order = sorted(ref)  # stamps (log order is stamp order here)
    rng = np.random.default_rng(30)
    cuts = sorted(rng.integers(chunks[2].chunk_start_offset, len(data) - 1, 8).tolist())
    for i, cut in enumerate(cuts):
        cut_path = tmp_path / f"cut{i}.mcap"
        cut_path.write_bytes(data[:cut])
        bag = open_bag(cut_path)
        assert not bag.info.complete
        got = read_joint_series(bag, "joint_torques", JOINT_NAMES, effort=True)
        stamps = got.stamp_ns.tolist()
        assert stamps == order[:len(stamps)], i  # a prefix: nothing skipped, nothing made up
        for k in range(0, len(stamps), 97):
            np.testing.assert_array_equal(got.effort[k], ref[stamps[k]][1])
        # the newest message the file had begun to hold at the cut
        started = max(c.message_end_time for c in chunks if c.chunk_start_offset < cut)
        kept = max(ref[s][0] for s in stamps)
        print(f"cut at byte {cut}: {len(stamps)} of {len(order)} torques kept, "
              f"{(started - kept) / 1e9:.3f} s before the cut lost")
        assert started - kept <= SPAN_NS, (i, (started - kept) / 1e9)
        rec = tmp_path / f"rec{i}.mcap"
        recover(cut_path, rec)
        back = rosbags_torques(rec)
        assert sorted(back) == stamps
        s = stamps[-1]
        np.testing.assert_array_equal(back[s][1], ref[s][1])


def test_export_of_a_cut_file_says_truncated_and_never_inf(made, tmp_path) -> None:
    _d, out, ref = made
    data = out.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    sto = tmp_path / "cut.sto"
    r = run("bag_export", cut, "--format", "sto", "--out", sto)
    assert r.returncode == 0, r.stderr
    assert "truncated" in r.stdout and "truncated" in r.stderr, r.stdout
    text = sto.read_text()
    head, body = text.split("endheader\n", 1)
    assert "truncated=yes" in head and "note_std=NaN" in head, head
    assert "inf" not in body.lower()
    table = osim.TimeSeriesTable(str(sto))  # OpenSim reads it, NaN where no σ is known
    sd = table.getDependentColumn("elbow_flexion_moment_std").to_numpy()
    n_warm = int(np.isnan(sd).sum())
    assert 2 <= n_warm < 100 and np.isfinite(sd[n_warm:]).all(), n_warm
    assert table.getNumRows() < len(ref)
    assert table.getTableMetaDataAsString("truncated").startswith("yes: cut.mcap was cut")
    csv_path = tmp_path / "full.csv"
    r = run("bag_export", out, "--format", "csv", "--out", csv_path)
    assert r.returncode == 0 and "truncated" not in r.stdout, r.stdout
    assert "inf" not in csv_path.read_text().lower()
    with open(csv_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(ref)
    empty = [row["elbow_flexion_moment_std"] == "" for row in rows]
    assert sum(empty) == n_warm and not any(empty[n_warm:]), sum(empty)


def test_check_bag_on_a_10hz_bag_picks_a_cutoff_and_says_which(tmp_path) -> None:
    """The first version exited 2 on a filter-cutoff error (6 Hz above the 5 Hz Nyquist)."""
    src, out = tmp_path / "slow.mcap", tmp_path / "slow_tq.mcap"
    write_stream_bag(src, 120, period_ns=100 * MS)
    r = run("bag_torques", src, out)
    assert r.returncode == 0 and "input at 10 Hz (stamp step 100.0 ms) is below the rates" in r.stderr, \
        r.stderr
    r = run("check_bag", out)
    assert r.returncode in (0, 1), r.stdout + r.stderr
    assert "low-passed at 4 Hz" in r.stdout and "Traceback" not in r.stderr, r.stdout
    r = run("check_bag", out, "--cutoff", "3")
    assert r.returncode in (0, 1) and "low-passed at 3 Hz" in r.stdout, r.stdout
    r = run("check_bag", out, "--cutoff", "6")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "cutoff 6 Hz must be in (0, 5) Hz" in r.stderr, r.stderr
