"""The real-time parameters of a node (realtime_priority, lock_memory, cpu_affinity) and
when they are applied (docs/realtime.md).

`common.run()` calls `start_realtime()` once the node and its executor exist, before the
spin: the middleware's receive, event and discovery threads exist by then and get the
policy with the executor thread; threads they start later inherit it; the node's helper
threads (`realtime_helpers()`: the torque node's model builder) are left normal. A refusal
is one warning naming what to change; the node serves on and states the policy it got
(`realtime_state.describe()`) in its config and /diagnostics.
"""

from __future__ import annotations

from typing import Any

from .. import realtime
from .params import ParameterError, Params, Spec

REALTIME_SPECS = (
    Spec("realtime_priority", 0, "SCHED_FIFO priority of the executor thread and the "
         "middleware's threads (not helper threads such as the model builder); 0 = normal "
         "scheduling. Needs CAP_SYS_NICE or RLIMIT_RTPRIO (limits.conf rtprio)", "", 0, 99),
    Spec("lock_memory", False, "mlockall(MCL_CURRENT | MCL_FUTURE) at start-up: no page "
         "faults on the hot path. Needs CAP_IPC_LOCK or RLIMIT_MEMLOCK (limits.conf memlock)"),
    Spec("cpu_affinity", "", "CPUs for every thread of the node: '' = any; '1', '0,2' or "
         "'2-3' (taskset -c syntax) or a list of integers", dynamic=True),
)


def parse_cpus(name: str, value: Any) -> tuple[int, ...]:
    """'' | '1' | '0,2-3' | [0, 1] -> sorted CPU numbers; ParameterError for anything else."""
    if isinstance(value, str):
        out: set[int] = set()
        for part in filter(None, (p.strip() for p in value.split(","))):
            lo, _, hi = part.partition("-")
            try:
                a, b = int(lo), int(hi or lo)
            except ValueError:
                raise ParameterError(name, f"{value!r} is not a CPU list (e.g. '1', '0,2', '2-3')") from None
            if a < 0 or b < a:
                raise ParameterError(name, f"{part!r} is not a CPU range")
            out.update(range(a, b + 1))
        return tuple(sorted(out))
    if isinstance(value, (list, tuple)) and all(isinstance(c, int) and not isinstance(c, bool)
                                                and c >= 0 for c in value):
        return tuple(sorted(set(value)))
    raise ParameterError(name, f"must be a CPU list string or a list of CPU numbers, got {value!r}")


def realtime_request(params: Params) -> realtime.RealtimeRequest:
    return realtime.RealtimeRequest(
        priority=params.value("realtime_priority"),
        lock_memory=params.value("lock_memory"),
        cpu_affinity=parse_cpus("cpu_affinity", params.value("cpu_affinity")),
    )


class RealtimeNode:
    """Mixin for a Node with REALTIME_SPECS: applies them (run() calls start_realtime)."""

    realtime_req: realtime.RealtimeRequest = realtime.RealtimeRequest()
    realtime_state: realtime.RealtimeState | None = None

    def realtime_helpers(self) -> tuple[int, ...]:
        """Thread ids (native) of helper threads to keep at normal priority."""
        return ()

    def start_realtime(self) -> realtime.RealtimeState:
        state = realtime.apply(self.realtime_req, exclude=self.realtime_helpers())
        self.realtime_state = state
        log = self.get_logger()
        for w in state.warnings:  # one per refused setting
            log.warning(w)
        if self.realtime_req.wanted:
            log.info(f"scheduling: {self.realtime_line()}")
        self.on_realtime_applied()
        return state

    def realtime_line(self) -> str:
        s = self.realtime_state
        if s is None:
            return "not applied"
        pol = f"fifo {s.priority}" if s.policy == "fifo" else s.policy
        n_rt = sum(t.policy in ("fifo", "rr") for t in s.threads)
        return (f"{pol} ({n_rt} of {len(s.threads)} threads real-time), memory "
                f"{'locked' if s.memory_locked else 'not locked'}, CPUs {','.join(map(str, s.cpus))}")

    def on_realtime_applied(self) -> None:
        """Hook: e.g. republish the node's config with the policy it got."""

    def realtime_values(self) -> dict[str, str]:
        s = self.realtime_state
        if s is None:
            return {"realtime.policy": "not applied"}
        d = s.describe()
        return {
            "realtime.policy": d["policy"],
            "realtime.priority": str(d["priority"]),
            "realtime.requested_priority": str(d["requested_priority"]),
            "realtime.memory_locked": str(d["memory_locked"]).lower(),
            "realtime.cpus": ",".join(map(str, d["cpus"])),
            "realtime.threads": f"{d['realtime_threads']} of {d['threads']} real-time",
            "realtime.rt_throttling": d["rt_throttling"],
        }
