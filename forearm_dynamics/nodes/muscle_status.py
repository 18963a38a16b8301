"""What muscle_node states about itself: the config message on `~/config` (muscle set,
sources, licences, scaling, solver, QoS; config_id and applies_from_stamp_ns), its
/diagnostics values (solve time, reserve use, infeasible samples, the model in force) and
the summary line it logs at shutdown.

A mixin of MuscleNode (as torque_status.py is of TorqueNode): none of it runs per sample
except the counters the callback bumps; the percentiles are computed once per period.
"""

from __future__ import annotations

import json
import os
import time

import numpy as np
from diagnostic_msgs.msg import KeyValue
from std_msgs.msg import String

from . import validation as v
from .diagnostics import diagnostic_array
from .muscle_settings import MuscleBundle

WARN_EVERY_S = 1.0


class MuscleStatus:
    """config / diagnostics / summary of the muscle node (see the module docstring)."""

    def config(self, b: MuscleBundle, applies_from: int | None) -> dict:
        s = self.settings
        return {
            "node": self.get_fully_qualified_name(), "version": self._version,
            "config_id": b.config_id, "applies_from_stamp_ns": applies_from,
            "input_topic": self.sub.topic_name if hasattr(self, "sub") else s.input_topic,
            "output_topic": self.pub.topic_name,
            "reserves_topic": self.reserves_pub.topic_name if self.reserves_pub is not None else None,
            "layout": {"output": "sensor_msgs/JointState: name = muscles, position = activation "
                                 "(0..1), velocity = muscle-tendon lengthening speed (m/s), effort = "
                                 "tendon force (N)",
                       "reserves": "sensor_msgs/JointState: name = joints, effort = reserve "
                                   "torque (N*m)"},
            "arm": b.arm_summary, "model_source": b.source,
            "torque_config_id": self._torque_config_id if b.source != "own parameters" else None,
            "muscles": b.model.config(),
            "solver": {"method": "static optimisation per sample, daqp (warm-started)",
                       "cost": "sum a^2 + sum (r / reserve_optimal_torque)^2",
                       "reserve_optimal_torque": s.reserve_optimal_torque,
                       "force_velocity": s.force_velocity, "passive": s.passive,
                       "tendon": "rigid"},
            "decimation": s.decimation, "build_ms": round(b.build_ms, 3),
            "input_qos": "reliable" if s.input_reliable else "best effort",
            "input_depth": s.input_depth, "backlog_limit": s.backlog_limit, "nice": os.nice(0),
        }

    def _publish_config(self, b: MuscleBundle, applies_from: int | None) -> None:
        self.config_pub.publish(String(data=json.dumps(self.config(b, applies_from))))

    def _executor_cpu_us_per_sample(self) -> float:
        """CPU time of this thread (the executor's: it runs every callback) since the last
        period, per sample answered: what a sample costs the node on its thread, waits for
        the CPU excluded (the callback's wall-clock compute_us includes them: on a loaded
        machine at nice 10 it is preempted). Read once per period: no per-sample clock."""
        now, done = time.thread_time_ns(), self.stats.published
        last = self._cpu_mark
        self._cpu_mark = (now, done)
        if last is None or done == last[1]:
            return float("nan")
        return (now - last[0]) / (done - last[1]) / 1e3

    def _publish_diagnostics(self) -> None:
        v.flush_suppressed(self._warned, self.get_logger(), WARN_EVERY_S)
        cpu = self._executor_cpu_us_per_sample()
        status = self.stats.status(f"{self.get_name()}: muscles", self.get_fully_qualified_name())
        n = min(self._n_solve, len(self._solve_ns))
        if n:
            p50, p99, pmax = (np.percentile(self._solve_ns[:n], (50, 99, 100)) / 1e3).tolist()
        else:
            p50 = p99 = pmax = float("nan")
        self._n_solve = 0
        b = self.bundle
        values = {
            "executor_cpu_us_per_sample": f"{cpu:.1f}",
            "solve_us_p50": f"{p50:.1f}", "solve_us_p99": f"{p99:.1f}", "solve_us_max": f"{pmax:.1f}",
            "decimation": str(self.settings.decimation), "decimated_total": str(self.decimated),
            "reserve_use_total": str(self.reserve_use),
            "reserve_max_nm": f"{self._max_reserve[0]:.3f}",
            "reserve_max_joint": self._max_reserve[1] or "none",
            "infeasible_total": str(self.infeasible), "solver_failed_total": str(self.solver_failed),
            "config_id": str(b.config_id), "muscles": str(b.model.n),
            "model": f"{b.arm_summary['body_size']} {b.model.side} arm ({b.source})",
            **self._backlog.period_values(),
        }
        status.values.extend(KeyValue(key=k, value=x) for k, x in values.items())
        bl = self._backlog
        if bl.dropped or bl.gaps:
            status.level = status.ERROR
            status.message = (f"input lost: {bl.dropped} dropped past backlog_limit, "
                              f"{bl.gaps} missing in the input's sequence numbers")
        elif self.infeasible and status.level == status.OK:
            status.level = status.WARN
            status.message = f"{self.infeasible} infeasible sample(s) (reserves carry torque)"
        self.diag_pub.publish(diagnostic_array(status, self.get_clock().now().to_msg()))
        self._publish_config(self.bundle, self.applies_from)

    def summary(self) -> str:
        st = self.stats
        rejected = {k: n for k, n in st.rejected.items() if n}
        return (f"summary: received {st.received}, solved {st.published}, decimated "
                f"{self.decimated}, rejected {sum(rejected.values())}"
                + (f" ({', '.join(f'{k} {n}' for k, n in rejected.items())})" if rejected else "")
                + f", infeasible {self.infeasible}, reserve use {self.reserve_use}"
                + f", backlog max {self._backlog.max_total} (drained {self._backlog.drained}, "
                f"dropped {self._backlog.dropped}, input gaps {self._backlog.gaps}, "
                f"unanswered at stop {len(self._backlog.pending)})")
