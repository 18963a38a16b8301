"""Whether this process may use real-time scheduling (root here and in CI): `needs_fifo`
skips a test of the nodes' realtime_priority where the kernel would refuse it, with the
reason. (No test relies on FIFO to get the CPU in time: a virtual machine's vCPU can be
taken away for 30-50 ms whatever the priority; see support/cpushare.py.)"""

from __future__ import annotations

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
