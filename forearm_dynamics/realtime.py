"""Real-time scheduling, memory locking and CPU affinity of a process's threads (no ROS).

Linux schedules threads, not processes: a policy set with sched_setscheduler(tid) holds for
that one thread, and a thread starts with the policy, priority and affinity of the thread
that creates it. A node therefore applies its policy once its middleware has started its
threads (the DDS receive, event and discovery threads exist once the rcl node does) and
gives it to every thread of the process that exists then, except the helper threads it
names (the torque node's model builder: a 2-5 ms build at FIFO priority would delay the
executor it must not disturb). Threads started later by a real-time thread inherit its
policy; a helper thread started later drops to normal itself (`make_normal`).

Everything is read back from the kernel (/proc/self/task/<tid>/stat, sched_getaffinity),
never assumed: `apply` returns what each thread got, and a refusal (no CAP_SYS_NICE,
RLIMIT_RTPRIO lower than asked, RLIMIT_MEMLOCK too small, a CPU outside the allowed set)
comes back as one sentence naming what to change. A runaway loop at FIFO priority cannot
lock the machine while the kernel's RT throttling is on (/proc/sys/kernel/
sched_rt_runtime_us < sched_rt_period_us: real-time threads get at most that share of each
period per CPU, 950 000 of 1 000 000 us by default); `throttling()` reads it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import resource
import threading
from dataclasses import dataclass, field
from pathlib import Path

MCL_CURRENT, MCL_FUTURE = 1, 2
_PR_SET_NAME = 15
_POLICY_NAMES = {os.SCHED_OTHER: "normal", os.SCHED_FIFO: "fifo", os.SCHED_RR: "rr",
                 getattr(os, "SCHED_BATCH", 3): "batch", getattr(os, "SCHED_IDLE", 5): "idle"}
_libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


@dataclass(frozen=True)
class RealtimeRequest:
    """What a node asks for: FIFO priority (0 = normal), mlockall, CPUs (empty = any)."""

    priority: int = 0
    lock_memory: bool = False
    cpu_affinity: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if not 0 <= self.priority <= 99:
            raise ValueError(f"realtime_priority must be 0 (off) or 1-99, got {self.priority}")
        bad = [c for c in self.cpu_affinity if c < 0]
        if bad:
            raise ValueError(f"cpu_affinity: {bad[0]} is not a CPU number")

    @property
    def wanted(self) -> bool:
        return bool(self.priority or self.lock_memory or self.cpu_affinity)


@dataclass(frozen=True)
class ThreadSched:
    """One thread's scheduling as the kernel states it (/proc/<pid>/task/<tid>/stat)."""

    tid: int
    name: str
    policy: str  # normal | fifo | rr | batch | idle
    priority: int  # rt_priority: 1-99 for fifo/rr, 0 otherwise


@dataclass
class RealtimeState:
    """What the process got: the policy of its threads, memory lock, CPUs, and refusals."""

    request: RealtimeRequest
    policy: str = "normal"  # of the applying (executor) thread, read back
    priority: int = 0
    memory_locked: bool = False
    cpus: tuple[int, ...] = ()
    threads: list[ThreadSched] = field(default_factory=list)
    excluded: tuple[int, ...] = ()  # helper threads left (or made) normal
    warnings: list[str] = field(default_factory=list)

    def describe(self) -> dict:
        """The JSON-able summary a node states in ~/config and /diagnostics."""
        rt = [t for t in self.threads if t.policy in ("fifo", "rr")]
        return {
            "policy": self.policy,
            "priority": self.priority,
            "requested_priority": self.request.priority,
            "memory_locked": self.memory_locked,
            "requested_lock_memory": self.request.lock_memory,
            "cpus": list(self.cpus),
            "requested_cpus": list(self.request.cpu_affinity),
            "realtime_threads": len(rt),
            "threads": len(self.threads),
            "rt_throttling": throttling(),
        }


def read_thread(pid: int, tid: int) -> ThreadSched | None:
    """A thread's name, policy and rt priority from /proc (None if it has exited)."""
    base = Path(f"/proc/{pid}/task/{tid}")
    try:
        stat = (base / "stat").read_text()
    except OSError:
        return None
    # "tid (comm) state ..." - comm may hold spaces or parentheses: split after the last ')'
    name = stat[stat.index("(") + 1:stat.rindex(")")]
    rest = stat[stat.rindex(")") + 2:].split()
    # fields 40 (rt_priority) and 41 (policy) of proc(5); rest[0] is field 3
    rt_priority, policy = int(rest[37]), int(rest[38])
    return ThreadSched(tid, name, _POLICY_NAMES.get(policy, str(policy)), rt_priority)


def read_threads(pid: int | None = None) -> list[ThreadSched]:
    pid = pid or os.getpid()
    try:
        tids = sorted(int(t) for t in os.listdir(f"/proc/{pid}/task"))
    except OSError:
        return []
    return [t for t in (read_thread(pid, tid) for tid in tids) if t is not None]


def throttling() -> str:
    """The kernel's RT throttling: 'R of P us' (R < P: a runaway FIFO loop leaves the rest)."""
    try:
        runtime = int(Path("/proc/sys/kernel/sched_rt_runtime_us").read_text())
        period = int(Path("/proc/sys/kernel/sched_rt_period_us").read_text())
    except (OSError, ValueError):
        return "unknown"
    if runtime < 0:
        return f"off (sched_rt_runtime_us -1 of {period} us: a runaway FIFO loop can hold a CPU)"
    return f"{runtime} of {period} us"


def set_thread_name(name: str) -> None:
    """The calling thread's kernel name (/proc/.../comm, top -H), at most 15 bytes."""
    _libc.prctl(_PR_SET_NAME, ctypes.c_char_p(name.encode()[:15]), 0, 0, 0)


def make_normal() -> None:
    """Drop the calling thread to SCHED_OTHER (a helper started by a real-time thread)."""
    if os.sched_getscheduler(0) != os.SCHED_OTHER:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def _rtprio_advice(priority: int) -> str:
    soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
    limit = "unlimited" if soft == resource.RLIM_INFINITY else str(soft)
    return (f"realtime_priority {priority} refused (RLIMIT_RTPRIO {limit}, no CAP_SYS_NICE): "
            f"running at normal priority; allow it with '<user> - rtprio {priority}' in "
            "/etc/security/limits.conf (log in again), `setcap cap_sys_nice+ep` on the "
            "interpreter, or in a container --cap-add SYS_NICE / --ulimit rtprio=99")


def _memlock_advice(err: int) -> str:
    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    limit = "unlimited" if soft == resource.RLIM_INFINITY else f"{soft // 1024} KiB"
    return (f"lock_memory refused ({os.strerror(err)}; RLIMIT_MEMLOCK {limit}, no "
            "CAP_IPC_LOCK): memory not locked; allow it with '<user> - memlock unlimited' in "
            "/etc/security/limits.conf or --cap-add IPC_LOCK / --ulimit memlock=-1")


def apply(request: RealtimeRequest, exclude: tuple[int, ...] = ()) -> RealtimeState:
    """Apply `request` to every thread of this process but `exclude` (tids); read it back.

    Call it from the executor thread once the middleware's threads exist. Never raises for
    a refusal: each refusal is one sentence in `warnings`, and the process runs on as the
    kernel left it.
    """
    state = RealtimeState(request, excluded=tuple(exclude))
    pid = os.getpid()
    tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    targets = [t for t in tids if t not in exclude]
    if request.cpu_affinity:
        allowed = os.sched_getaffinity(0)
        wanted = set(request.cpu_affinity)
        if not wanted <= allowed:
            state.warnings.append(
                f"cpu_affinity {sorted(wanted)} refused: CPU(s) {sorted(wanted - allowed)} "
                f"not available to this process (allowed: {sorted(allowed)}); running on any")
        else:
            for tid in tids:  # helpers too: the whole process stays on these CPUs
                try:
                    os.sched_setaffinity(tid, wanted)
                except ProcessLookupError:
                    pass
    if request.priority:
        param = os.sched_param(request.priority)
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, param)  # the caller first: the test
            for tid in targets:
                try:
                    os.sched_setscheduler(tid, os.SCHED_FIFO, param)
                except ProcessLookupError:
                    pass
        except PermissionError:
            state.warnings.append(_rtprio_advice(request.priority))
    for tid in exclude:  # a helper the calling thread started before: keep it normal
        try:
            if os.sched_getscheduler(tid) != os.SCHED_OTHER:
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
        except (ProcessLookupError, PermissionError):
            pass
    if request.lock_memory:
        if _libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
            state.memory_locked = True
        else:
            state.warnings.append(_memlock_advice(ctypes.get_errno() or errno.ENOMEM))
    state.threads = read_threads(pid)
    me = read_thread(pid, threading.get_native_id())
    if me is not None:
        state.policy, state.priority = me.policy, me.priority
    state.cpus = tuple(sorted(os.sched_getaffinity(0)))
    if not state.memory_locked:
        state.memory_locked = _locked_now()
    return state


def _locked_now() -> bool:
    """mlockall in force (VmLck covers nearly all of VmSize)? For a state read back."""
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return False
    vals = {k: int(v.split()[0]) for k, _, v in (line.partition(":") for line in text.splitlines())
            if k in ("VmLck", "VmSize") and v.strip()}
    return vals.get("VmLck", 0) > 0 and vals.get("VmLck", 0) >= 0.9 * vals.get("VmSize", 1)
