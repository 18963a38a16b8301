"""A CPU quota for one process: a node short of CPU, without loading the machine.

Why a quota rather than a burst faster than the node: a burst claim needs the node to react
within its queue's span (500 samples at 40 kHz: 12.5 ms), and a virtual machine's vCPU is
sometimes taken away for longer than that whatever the node's priority (this machine, with
heavy disk writes beside: steal in 30-50 ms chunks, /proc/stat). A quota makes the node slow
the way a loaded machine does, at the real input rate, where such a pause costs 50 samples.

Used by benchmarks/two_host_run.py (`node_cpu`) and test_muscle_node's backlog test. cgroup
v1 cpu controller (this machine and CI; root)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Self

import pytest

ROOT = Path("/sys/fs/cgroup/cpu")


def why_no_cpu_share() -> str | None:
    """None where a CpuShare can be made here, else why not."""
    if not (ROOT / "cpu.cfs_quota_us").exists():
        return f"no cgroup v1 cpu controller at {ROOT}"
    if not os.access(ROOT, os.W_OK):
        return f"{ROOT} not writable (needs root)"
    return None


needs_cpu_share = pytest.mark.skipif(why_no_cpu_share() is not None,
                                     reason=str(why_no_cpu_share()))


class CpuShare:
    """A cgroup giving its processes `percent` % of one CPU (cfs quota per `period_us`).
    None: no limit. Its processes go back to the root cgroup on exit (the cgroup is removed).
    Only normal-priority threads are limited (SCHED_FIFO threads are not CFS's)."""

    def __init__(self, percent: float | None, period_us: int = 100_000) -> None:
        self.percent, self.period_us = percent, period_us
        self.path = ROOT / f"fdcpu{os.getpid()}_{id(self):x}"

    def __enter__(self) -> Self:
        if self.percent is not None:
            self.path.mkdir()
            try:  # the kernel refuses a quota under 1 ms (EINVAL): no cgroup left behind
                (self.path / "cpu.cfs_period_us").write_text(str(self.period_us))
                quota = round(self.period_us * self.percent / 100)
                (self.path / "cpu.cfs_quota_us").write_text(str(quota))
            except OSError:
                self.path.rmdir()
                raise
        return self

    def add(self, pid: int) -> None:
        """Move a process (all its threads, and those it makes later) into the cgroup, from
        outside: `ip netns exec` mounts a /sys of its own, without the cgroup tree."""
        if self.percent is not None:
            (self.path / "cgroup.procs").write_text(str(pid))

    def add_threads(self, pid: int, skip_prefix: str = "dds.") -> list[str]:
        """Move the threads of `pid` whose name does not start with `skip_prefix` (Fast DDS
        names its receive, event and watchdog threads dds.*); returns the names moved. A
        cgroup v1 controller holds threads one by one: the node's executor short of CPU
        while its middleware still receives, as when its callbacks are slow."""
        moved = []
        for tid in os.listdir(f"/proc/{pid}/task"):
            name = Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
            if not name.startswith(skip_prefix) and self.percent is not None:
                (self.path / "tasks").write_text(tid)
                moved.append(name)
        return moved

    def __exit__(self, *exc) -> None:
        if self.percent is not None and self.path.exists():
            for tid in (self.path / "tasks").read_text().split():
                try:
                    (ROOT / "tasks").write_text(tid)  # any left: back to the root
                except ProcessLookupError:
                    pass  # exited meanwhile
            self.path.rmdir()
