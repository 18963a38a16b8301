"""Times the estimator and the callback's parts inside a running torque_node (issue 29 item 5).

Why: the node's callback p50 moves by ±20 µs between runs of the same code (other load,
caches), more than a change to one part of the estimator; timing the parts inside the node
resolves a few µs. Not imported unless asked: with this directory on PYTHONPATH and
ESTIMATOR_PROBE=FILE set, every torque_node process wraps, with perf_counter_ns, the
estimator's update() (KalmanCA's: `update`, BackwardDifference's: `backward_update`),
KalmanCA.learn (only where it had
a sample to take), the torques (ModelBundle.torques: the RNEA), TorqueNode.compute (the
callback's work from the decoded sample to the torques, the update and the torques inside
it) and TorqueNode.after_output (after the publish: learn(), the σ when published), and at
exit appends one line to FILE: p50 / p90 / p99 in µs of each part that ran. With --choices
default,backward_estimator the two nodes' lines compare part by part. Example
(docs/performance.md):

    ESTIMATOR_PROBE=/tmp/probe.txt PYTHONPATH=benchmarks/estimator_probe \\
        python -m benchmarks --sections choices --choices default --out /tmp/probe.json
"""

import atexit
import os
import sys
import time

if os.environ.get("ESTIMATOR_PROBE") and "torque_node" in " ".join(sys.argv):
    from forearm_dynamics.estimation import backward, kalman
    from forearm_dynamics.nodes import torque_config, torque_node

    _times: dict[str, list[int]] = {}
    _clock = time.perf_counter_ns

    def _wrap(cls, name: str, key: str) -> None:
        """cls.name timed into _times[key]."""
        f = getattr(cls, name)
        times = _times.setdefault(key, [])

        def timed(self, *args):
            t = _clock()
            out = f(self, *args)
            times.append(_clock() - t)
            return out

        setattr(cls, name, timed)

    _wrap(kalman.KalmanCA, "update", "update")
    _wrap(backward.BackwardDifference, "update", "backward_update")
    _learn = kalman.KalmanCA.learn
    _times["learn"] = []

    def _timed_learn(self):
        pending = self._pending
        t = _clock()
        _learn(self)
        if pending:
            _times["learn"].append(_clock() - t)

    kalman.KalmanCA.learn = _timed_learn
    _wrap(torque_config.ModelBundle, "torques", "torques")
    _wrap(torque_node.TorqueNode, "compute", "compute")
    _wrap(torque_node.TorqueNode, "after_output", "after_output")

    def _report() -> None:
        import numpy as np

        parts = [f"pid {os.getpid()}"]
        for name, v in _times.items():
            if len(v) > 100:
                p = np.percentile(np.array(v) / 1e3, [50, 90, 99])
                parts.append(f"{name} n={len(v)} p50={p[0]:.2f} p90={p[1]:.2f} p99={p[2]:.2f} µs")
        if len(parts) > 1:  # a process that ran a filter (not a launcher of one)
            with open(os.environ["ESTIMATOR_PROBE"], "a", encoding="utf-8") as f:
                f.write("; ".join(parts) + "\n")

    atexit.register(_report)
