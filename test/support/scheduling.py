"""Real-time scheduling for tests that need the CPU at a given moment (root here and in CI).

A test whose claim needs a process to run during a burst (a node taking samples as they
arrive) cannot get it from a shared machine at normal priority: a second `make test` beside
it starves either side for tens of ms. SCHED_FIFO threads run before every normal one, so
the claim holds whatever else the machine does; where FIFO is not allowed, `needs_fifo`
skips with the reason."""

from __future__ import annotations

import contextlib
import os
import resource
from pathlib import Path

import pytest


def may_set_fifo(priority: int = 50) -> bool:
    """CAP_SYS_NICE (root here, CI) or an RLIMIT_RTPRIO of at least `priority`."""
    soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
    if soft == resource.RLIM_INFINITY or soft >= priority:
        return True
    status = Path("/proc/self/status").read_text().splitlines()
    caps = next(line for line in status if line.startswith("CapEff"))
    return bool(int(caps.split()[1], 16) & (1 << 23))  # CAP_SYS_NICE


needs_fifo = pytest.mark.skipif(not may_set_fifo(), reason="needs CAP_SYS_NICE or rtprio >= 50")


def fifo_process(pid: int, priority: int) -> int:
    """Every thread `pid` has now to SCHED_FIFO `priority` (threads it starts later inherit
    their creator's policy); returns how many."""
    tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    for tid in tids:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
    return len(tids)


@contextlib.contextmanager
def fifo_thread(priority: int):
    """The calling thread at SCHED_FIFO `priority` inside the block, normal after it."""
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    try:
        yield
    finally:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
