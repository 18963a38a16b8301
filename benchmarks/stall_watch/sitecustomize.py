"""Which process stalls, and where, in a benchmark's run (the ~335 ms gaps, docs/performance.md).

Why: the node benchmark's receiver sees, in about one run in ten (and in the first run after
a machine starts), one gap of 265-336 ms, always 3.3-4.0 s after the publisher started, while
the torque node's own callback max stays at a few ms. Which of the publisher, the node, the
receiver or DDS holds the samples is not in the benchmark's figures. Not imported unless
asked: with this directory on PYTHONPATH and STALL_WATCH=FILE set, every Python process the
run starts gets a thread that wakes every 10 ms and, when it wakes more than LATE_S late,
appends to FILE the process, how late, how much of that its thread waited for a CPU
(/proc schedstat: the machine, not the GIL) and every other thread's stack at that moment;
and, every 0.2 s, the modules imported since (a lazy import mid-stream reads files: slow on
a cold page cache). Example:

    STALL_WATCH=/tmp/stalls.txt PYTHONPATH=benchmarks/stall_watch \\
        python -m benchmarks --sections choices --choices default,backward_estimator --out F

Start-up lines (imports, the first collection before gc.freeze) are expected; a stall while
streaming names its process. 20 runs on 2026-12-07 (04:42-04:47 UTC, load 0.1-1.3) had no
gap and no late wake while streaming; four more (04:47-04:49) no import while streaming.
"""

import os
import sys
import threading
import time
import traceback

LATE_S = 0.06  # a wake this late (beyond its 10 ms) is reported
PERIOD_S = 0.01

OUT = os.environ.get("STALL_WATCH")
if OUT:
    _who = f"{os.getpid()} {os.path.basename(sys.argv[0])} {' '.join(sys.argv[1:4])}"
    _t0 = time.monotonic()

    def _runqueue_ns() -> int:
        """Time this thread has waited for a CPU (ns), 0 where /proc does not say."""
        try:
            with open(f"/proc/self/task/{threading.get_native_id()}/schedstat") as f:
                return int(f.read().split()[1])
        except (OSError, ValueError, IndexError):
            return 0

    def _report(text: str) -> None:
        with open(OUT, "a") as f:
            f.write(f"== {_who} t+{time.monotonic() - _t0:.2f} s: {text}\n")

    def _watch() -> None:
        last, waited, seen = time.monotonic(), _runqueue_ns(), set(sys.modules)
        checks = 0
        while True:
            time.sleep(PERIOD_S)
            now, rq = time.monotonic(), _runqueue_ns()
            late = now - last - PERIOD_S
            if late > LATE_S:
                me = threading.get_ident()
                stacks = ["".join(traceback.format_stack(f, limit=8))
                          for tid, f in sys._current_frames().items() if tid != me]
                _report(f"woke {late * 1e3:.1f} ms late (waiting for a CPU "
                        f"{(rq - waited) / 1e6:.1f} ms)\n" + "\n".join(stacks))
            last, waited = now, rq
            checks += 1
            if checks % 20 == 0:
                modules = set(sys.modules)
                if modules - seen:
                    _report(f"imported {sorted(modules - seen)[:12]} ({len(modules - seen)})")
                seen = modules

    threading.Thread(target=_watch, daemon=True, name="stall_watch").start()
