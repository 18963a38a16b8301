"""Benchmark and test support: CPU and memory of processes read from /proc while they run.

Not part of the installed package (only benchmarks/ and test/ sample /proc); moved out of
forearm_dynamics/processes.py, which keeps what the tools themselves run (Child, ros_env,
domain leases).
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from typing import Self

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


# -- /proc sampling ---------------------------------------------------------------------------
@dataclass(frozen=True)
class ProcStat:
    """One reading of a live process."""

    cpu_s: float  # utime + stime
    rss_kb: int  # VmRSS
    hwm_kb: int  # VmHWM (peak RSS)


def proc_stat(pid: int) -> ProcStat | None:
    """CPU seconds and memory of a live process from /proc; None once it is gone.

    An exited child not yet reaped (a zombie) has no memory lines: None too, not zeros.
    """
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        cpu = (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime (fields 14, 15)
        rss = hwm = None
        with open(f"/proc/{pid}/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    rss = int(line.split()[1])
                elif line.startswith("VmHWM:"):
                    hwm = int(line.split()[1])
    except (OSError, IndexError, ValueError):
        return None
    if rss is None or hwm is None:
        return None
    return ProcStat(cpu, rss, hwm)


def machine_busy() -> float | None:
    """CPU seconds the whole machine spent busy (all cores, /proc/stat: not idle, not iowait)."""
    try:
        with open("/proc/stat", encoding="ascii") as fh:
            fields = [int(x) for x in fh.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)
    return (sum(fields[:8]) - idle) / CLOCK_TICKS


@dataclass
class Samples:
    """Time series of one process: wall time (time.time(), s), CPU s, RSS kB, HWM kB."""

    t: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)
    rss: list[int] = field(default_factory=list)
    hwm: list[int] = field(default_factory=list)

    def cpu_percent(self, t0: float, t1: float) -> float | None:
        """CPU use in % of one core between wall times t0 and t1 (nearest samples inside)."""
        idx = [i for i, t in enumerate(self.t) if t0 <= t <= t1]
        if len(idx) < 2:
            return None
        a, b = idx[0], idx[-1]
        span = self.t[b] - self.t[a]
        return 100.0 * (self.cpu[b] - self.cpu[a]) / span if span > 0 else None

    def rss_between(self, t0: float, t1: float) -> list[int]:
        return [r for t, r in zip(self.t, self.rss, strict=True) if t0 <= t <= t1]

    def peak_hwm_kb(self) -> int | None:
        return max(self.hwm) if self.hwm else None


class Sampler:
    """Reads /proc of some processes every `period` s in a thread.

    `series[name]`: that process's Samples; `machine`: the whole machine's busy CPU time
    (cpu only), so the CPU used by processes other than ours can be reported
    (`foreign_cpu_percent`); `load`: (wall time, 1-min load average) pairs.
    Use as a context manager, or start()/stop().
    """

    def __init__(self, pids: dict[str, int], period: float = 0.25):
        self.pids = dict(pids)
        self.period = period
        self.series = {name: Samples() for name in pids}
        self.machine = Samples()
        self.load: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="proc-sampler", daemon=True)

    def add(self, name: str, pid: int) -> None:
        self.series.setdefault(name, Samples())
        self.pids[name] = pid

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.sample()
            self._stop.wait(self.period)

    def foreign_cpu_percent(self, t0: float, t1: float) -> float | None:
        """% of one core used between t0 and t1 by every process but the sampled ones."""
        total = self.machine.cpu_percent(t0, t1)
        ours = [s.cpu_percent(t0, t1) for s in self.series.values()]
        if total is None or any(x is None for x in ours):
            return None
        return max(total - sum(ours), 0.0)

    def sample(self) -> None:
        now = time.time()
        self.load.append((now, os.getloadavg()[0]))
        busy = machine_busy()
        if busy is not None:
            self.machine.t.append(now)
            self.machine.cpu.append(busy)
            self.machine.rss.append(0)
            self.machine.hwm.append(0)
        for name, pid in list(self.pids.items()):
            st = proc_stat(pid)
            if st is None:
                continue
            s = self.series[name]
            s.t.append(time.time())
            s.cpu.append(st.cpu_s)
            s.rss.append(st.rss_kb)
            s.hwm.append(st.hwm_kb)
