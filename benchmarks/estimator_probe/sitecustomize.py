"""Times the Kalman filter's update() and learn() inside a running torque_node (issue 29 item 5).

Why: the node's callback p50 moves by ±20 µs between runs of the same code (other load,
caches), more than a change to one part of the estimator; timing the parts inside the node
resolves a few µs. Not imported unless asked: with this directory on PYTHONPATH and
ESTIMATOR_PROBE=FILE set, every torque_node process wraps KalmanCA.update and KalmanCA.learn
with perf_counter_ns and, at exit, appends one line to FILE (p50 / p90 / p99 in µs of both;
learn only where it had a sample to take). Example (docs/performance.md):

    ESTIMATOR_PROBE=/tmp/probe.txt PYTHONPATH=benchmarks/estimator_probe \\
        python -m benchmarks --sections choices --choices default --out /tmp/probe.json
"""

import atexit
import os
import sys
import time

if os.environ.get("ESTIMATOR_PROBE") and "torque_node" in " ".join(sys.argv):
    from forearm_dynamics.estimation import kalman

    _update, _learn = kalman.KalmanCA.update, kalman.KalmanCA.learn
    _times: dict[str, list[int]] = {"update": [], "learn": []}
    _clock = time.perf_counter_ns

    def _timed_update(self, *args):
        t = _clock()
        warm = _update(self, *args)
        _times["update"].append(_clock() - t)
        return warm

    def _timed_learn(self):
        pending = self._pending
        t = _clock()
        _learn(self)
        if pending:
            _times["learn"].append(_clock() - t)

    kalman.KalmanCA.update, kalman.KalmanCA.learn = _timed_update, _timed_learn

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
