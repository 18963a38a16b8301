"""Real-time options of torque_node as real processes, read back from /proc (never from
the node's own word): SCHED_FIFO 50 on the executor and middleware threads with the model
builder normal; a refused priority (CAP_SYS_NICE dropped, RLIMIT_RTPRIO 0) gives one
warning, the node serves and says `policy: normal`; deadline misses counted for a slow
node, none for a fast one, `queued` for a starved one; a busy FIFO process leaves a
normal process on its CPU some time (the kernel's RT throttling)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rosproc
from faultkit import TorqueHarness, joint_state
from std_msgs.msg import String
from support.scheduling import needs_fifo

from forearm_dynamics import realtime
from forearm_dynamics.nodes.common import latched_qos

pytestmark = pytest.mark.ros


def _threads(pid: int) -> list[realtime.ThreadSched]:
    """Every thread of `pid` as /proc states it (stat fields 40, 41), read by this process."""
    return realtime.read_threads(pid)


def _config(h: TorqueHarness) -> dict:
    got: list[str] = []
    h.peer.node.create_subscription(String, "/torque_node/config", lambda m: got.append(m.data),
                                    latched_qos())
    ok = h.peer.spin_until(lambda: any('"realtime": {"policy"' in g and '"threads"' in g for g in got), 15)
    assert ok, f"no config with the scheduling it got: {got}"
    return json.loads(got[-1])


@needs_fifo
def test_priority_50_on_executor_and_middleware_threads_not_the_builder(procs):
    h = TorqueHarness(procs, "-p", "realtime_priority:=50")
    try:
        pid = h.proc.pid
        threads = {t.tid: t for t in _threads(pid)}
        main = threads[pid]  # the executor spins on the main thread
        assert (main.policy, main.priority) == ("fifo", 50), threads
        dds = [t for t in threads.values() if t.name.startswith("dds.")]
        assert dds, f"no middleware threads found: {threads}"
        assert all((t.policy, t.priority) == ("fifo", 50) for t in dds), dds
        builders = [t for t in threads.values() if t.name == "model_builder"]
        assert len(builders) == 1, threads
        assert (builders[0].policy, builders[0].priority) == ("normal", 0), builders
        watchers = [t for t in threads.values() if t.name == "stop_watch"]  # nodes/common.spin
        assert [(t.policy, t.priority) for t in watchers] == [("normal", 0)], threads
        cfg = _config(h)["realtime"]
        assert (cfg["policy"], cfg["priority"]) == ("fifo", 50), cfg
        d = h.diag.fresh(lambda d: "realtime.policy" in d)
        assert d["realtime.policy"] == "fifo" and d["realtime.priority"] == "50", d
        # a live change is built on the normal-priority builder and served at FIFO
        h.exchange([joint_state(h.stamp()) for _ in range(5)])
    finally:
        h.close()


@pytest.mark.skipif(shutil.which("setpriv") is None or shutil.which("prlimit") is None,
                    reason="needs setpriv and prlimit (util-linux)")
def test_refused_priority_warns_once_serves_and_says_normal(procs, monkeypatch):
    """CAP_SYS_NICE dropped from the bounding set (so root loses it at exec) and
    RLIMIT_RTPRIO 0: the kernel refuses SCHED_FIFO, as for an ordinary user."""
    real_start = procs.start

    def start_unprivileged(executable, *ros_args, domain):
        argv = ["prlimit", "--rtprio=0", "setpriv", "--inh-caps=-sys_nice",
                "--bounding-set=-sys_nice", "--", str(rosproc.BIN / executable),
                "--ros-args", *ros_args]
        p = rosproc.NodeProcess("torque_node", argv, rosproc.ros_env(domain),
                                rosproc._LOG_DIR, split_stderr=True)
        return procs.add(p)

    monkeypatch.setattr(procs, "start", start_unprivileged)
    h = TorqueHarness(procs, "-p", "realtime_priority:=50")
    monkeypatch.setattr(procs, "start", real_start)
    try:
        replies = h.exchange([joint_state(h.stamp()) for _ in range(20)])
        assert replies, "the node does not serve"
        threads = _threads(h.proc.pid)
        assert all(t.policy == "normal" for t in threads), threads
        cfg = _config(h)["realtime"]
        assert cfg["policy"] == "normal" and cfg["requested_priority"] == 50, cfg
        d = h.diag.fresh(lambda d: "realtime.policy" in d)
        assert d["realtime.policy"] == "normal", d
        text = h.proc.output()
        warnings = [line for line in text.splitlines() if "realtime_priority 50 refused" in line]
        assert len(warnings) == 1, text
        assert "WARN" in warnings[0] and "limits.conf" in warnings[0] and "CAP_SYS_NICE" in warnings[0]
        assert "Traceback" not in text
    finally:
        h.close()


def test_slow_outputs_count_misses_and_fast_ones_none(procs):
    """deadline_ms 0.001 (1 us: every callback takes longer) counts every output as a
    `compute` miss; deadline_ms 5000 on the same traffic counts none."""
    results = {}
    for deadline in ("0.001", "5000.0"):
        h = TorqueHarness(procs, "-p", f"deadline_ms:={deadline}")
        try:
            h.exchange([joint_state(h.stamp()) for _ in range(200)])
            d = h.diag.fresh(lambda d: int(d.get("deadline_checked_total", 0)) >= 200)
            results[deadline] = d
            h.proc.stop()
            summary = [line for line in h.proc.output().splitlines() if "summary:" in line]
            assert summary and f"deadline {float(deadline):g} ms: missed" in summary[-1], summary
        finally:
            h.close()
    slow, fast = results["0.001"], results["5000.0"]
    assert int(slow["deadline_missed_total"]) == int(slow["deadline_checked_total"]) >= 200, slow
    assert int(slow["deadline_missed.compute"]) >= 1, slow
    assert float(slow["deadline_worst_ms"]) > 0.001, slow
    assert int(fast["deadline_missed_total"]) == 0, fast
    assert int(fast["deadline_checked_total"]) >= 200, fast


def test_starved_node_counts_queued_misses(procs):
    """The node stopped (SIGSTOP) 0.5 s while live samples keep coming: when it resumes,
    the inputs that waited count as `queued` misses (deadline 100 ms), none is skipped."""
    h = TorqueHarness(procs, "-p", "deadline_ms:=100.0")
    try:
        h.exchange([joint_state(h.stamp()) for _ in range(10)])
        before = h.diag.fresh()
        os.kill(h.proc.pid, signal.SIGSTOP)
        try:
            msgs = []
            for _ in range(50):  # 50 samples over 0.5 s, stamped at their send time
                m = joint_state(h.stamp(10 * 1_000_000))
                h.pub.publish(m)
                msgs.append(m)
                time.sleep(0.01)
        finally:
            os.kill(h.proc.pid, signal.SIGCONT)
        h.replies.clear()
        last = msgs[-1].header.stamp
        ok = h.peer.spin_until(lambda: any(r.header.stamp == last for r in h.replies), 15)
        assert ok, h.proc.output()[-2000:]
        d = h.diag.fresh(lambda d: int(d["processed_total"]) >= int(before["processed_total"]) + 50)
        assert int(d["deadline_missed.queued"]) >= 10, d
        assert float(d["deadline_worst_ms"]) >= 200, d
        assert int(d["processed_total"]) - int(before["processed_total"]) == 50, d  # all published
    finally:
        h.close()


BUSY = ("import time\nt0 = time.monotonic()\nend = t0 + {s}\nwhile time.monotonic() < end:\n"
        "    pass\nprint(t0, time.monotonic())\n")
TICKS = ("import time\nend = time.monotonic() + {s}\nlast, ticks = 0.0, []\n"
         "while (t := time.monotonic()) < end:\n    if t - last > 0.001:\n"
         "        ticks.append(t)\n        last = t\nprint(*ticks)\n")


@needs_fifo
def test_busy_fifo_process_leaves_a_normal_process_some_cpu():
    """A runaway loop at SCHED_FIFO 50 for 1.5 s beside a normal loop that notes the time
    every ms it runs, both pinned to one CPU: the normal loop notes times inside the FIFO
    loop's run (RT throttling: sched_rt_runtime_us < period leaves it ~5 % by default);
    without throttling it could not run at all until the FIFO loop ended."""
    runtime = int(Path("/proc/sys/kernel/sched_rt_runtime_us").read_text())
    period = int(Path("/proc/sys/kernel/sched_rt_period_us").read_text())
    assert 0 <= runtime < period, f"RT throttling is off ({runtime} of {period} us): unsafe"
    cpu = {max(os.sched_getaffinity(0))}
    normal = subprocess.Popen([sys.executable, "-c", TICKS.format(s=4.0)],
                              stdout=subprocess.PIPE, text=True)
    busy = None
    try:
        os.sched_setaffinity(normal.pid, cpu)
        time.sleep(0.5)  # the normal loop is running
        busy = subprocess.Popen([sys.executable, "-c", BUSY.format(s=1.5)],
                                stdout=subprocess.PIPE, text=True)
        os.sched_setaffinity(busy.pid, cpu)  # before its loop: it starts up for ~30 ms
        os.sched_setscheduler(busy.pid, os.SCHED_FIFO, os.sched_param(50))
        assert realtime.read_thread(busy.pid, busy.pid).policy == "fifo"
        t0, t1 = map(float, busy.communicate(timeout=30)[0].split())
        ticks = [float(x) for x in normal.communicate(timeout=30)[0].split()]
    finally:
        for p in (normal, busy):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(timeout=10)
    inside = [t for t in ticks if t0 + 0.1 < t < t1 - 0.1]
    # 1.3 s of FIFO loop: ~65 ms of the CPU left to others by throttling (some to other load)
    assert len(inside) >= 3, f"the normal loop never ran while the FIFO loop did ({t0}..{t1})"
