"""Child processes for the benchmarks: loopback-only ROS environment, stop by PID, /proc sampling.

Every child gets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and the bench's own ROS_DOMAIN_ID
(never 0); ROS/RMW/Fast DDS variables of the caller are not inherited, only what the bench
passes explicitly (e.g. a Fast DDS transport profile). Children are stopped by their own
PID only (SIGINT, then SIGKILL if they hang).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Self

from ..rosenv import ros_env  # noqa: F401 - re-exported for the bench modules

BIN = Path(sys.executable).parent  # the venv's console scripts sit next to its python
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")




class Child:
    """One started process; output to a log file so a chatty child never blocks."""

    def __init__(self, name: str, argv: list[str], env: dict[str, str], log_dir: Path,
                 cpus: set[int] | None = None):
        """`cpus`: CPU affinity of the process and every thread it starts (None: any)."""
        self.name = name
        self.log = log_dir / f"{name}.log"
        with self.log.open("wb") as fh:
            self.proc = subprocess.Popen(argv, env=env, stdout=fh, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL)
        if cpus:
            # Popen returns once exec succeeded: the child has one thread, and every thread
            # it starts later (rclpy, Fast DDS) inherits this affinity.
            os.sched_setaffinity(self.proc.pid, cpus)

    @classmethod
    def script(cls, name: str, ros_args: list[str], env: dict[str, str], log_dir: Path,
               label: str | None = None, cpus: set[int] | None = None) -> Child:
        """A console script of this venv with `--ros-args *ros_args`."""
        argv = [str(BIN / name)] + (["--ros-args", *ros_args] if ros_args else [])
        return cls(label or name, argv, env, log_dir, cpus)

    @classmethod
    def module(cls, name: str, module: str, args: list[str], env: dict[str, str],
               log_dir: Path, cpus: set[int] | None = None) -> Child:
        return cls(name, [sys.executable, "-m", module, *args], env, log_dir, cpus)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def running(self) -> bool:
        return self.proc.poll() is None

    def text(self) -> str:
        try:
            return self.log.read_text(errors="replace")
        except OSError:
            return ""

    def wait_for(self, text: str, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.text():
                return True
            if not self.running():
                return text in self.text()
            time.sleep(0.05)
        return False

    def wait(self, timeout: float) -> int | None:
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, timeout: float = 15.0) -> int:
        """SIGINT this process only; SIGKILL if it has not exited after `timeout` s."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        return self.proc.returncode


def proc_stat(pid: int) -> tuple[float, int, int] | None:
    """(utime + stime in s, VmRSS kB, VmHWM kB) of a live process, None once it is gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        cpu = (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime (fields 14, 15)
        rss = hwm = 0
        with open(f"/proc/{pid}/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    rss = int(line.split()[1])
                elif line.startswith("VmHWM:"):
                    hwm = int(line.split()[1])
    except (OSError, IndexError, ValueError):
        return None
    return cpu, rss, hwm


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
    """Reads /proc/<pid>/stat and status of some processes every `period` s in a thread.

    `machine` is the whole machine's busy CPU time (as a Samples with cpu only), so the
    CPU used by processes other than ours during a run can be reported (`foreign_cpu`).
    """

    def __init__(self, pids: dict[str, int], period: float = 0.25):
        self.pids = dict(pids)
        self.period = period
        self.series = {name: Samples() for name in pids}
        self.machine = Samples()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="proc-sampler", daemon=True)

    def add(self, name: str, pid: int) -> None:
        self.series.setdefault(name, Samples())
        self.pids[name] = pid

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

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
        busy = machine_busy()
        if busy is not None:
            self.machine.t.append(time.time())
            self.machine.cpu.append(busy)
            self.machine.rss.append(0)
            self.machine.hwm.append(0)
        for name, pid in list(self.pids.items()):
            st = proc_stat(pid)
            if st is None:
                continue
            s = self.series[name]
            s.t.append(time.time())
            s.cpu.append(st[0])
            s.rss.append(st[1])
            s.hwm.append(st[2])
