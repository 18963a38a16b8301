"""The noise estimator's add() per sample: paced like a node at 1 kHz, and back to back.

    .venv/bin/python benchmarks/noise_cost.py [--samples 6000] [--joints 20]

Why paced: a node sleeps ~0.9 ms between samples and each call then runs on cold caches, so
a loop's back-to-back figure understates what the node pays several times over (docs/
performance.md). Each case feeds a 1 kHz stream with ±10 % stamp jitter (a publisher's
clock), a slow movement plus 0.06° noise on every joint, positions only or with velocities,
once with the compiled store (estimation/noise_step.py) and once storing in Python (the
reference the store replaces); the first 1 000 samples are discarded. Prints p50 / p90 / p99
in µs. Timing is noisy on a shared machine: state `uptime` with the numbers.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from forearm_dynamics.estimation.noise import NoiseEstimator

WARMUP = 1000


def run(joints: int, samples: int, velocities: bool, compiled: bool, paced: bool) -> np.ndarray:
    rng = np.random.default_rng(0)
    est = NoiseEstimator(joints) if compiled else NoiseEstimator(joints).python_store()
    q, qd = np.zeros(joints), np.zeros(joints)
    t_ns, out = 10**18, []
    clock = time.perf_counter_ns
    for k in range(samples):
        t_ns += 1_000_000 + int(rng.integers(-100_000, 100_000))
        q[:] = np.sin(k * 1e-3) + rng.normal(0.0, 1e-3, joints)
        qd[:] = np.cos(k * 1e-3) + rng.normal(0.0, 1e-2, joints)
        if paced:
            time.sleep(0.0009)
        t = clock()
        est.add(t_ns, q, qd if velocities else None)
        out.append(clock() - t)
    return np.array(out[WARMUP:]) / 1e3


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=6000)
    ap.add_argument("--joints", type=int, default=20)
    args = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.2f}; {args.joints} joints, 1 kHz ±10 % jitter")
    print("| input | store | paced p50 / p90 / p99 µs | back to back p50 / p90 µs |")
    print("|---|---|---|---|")
    for velocities in (False, True):
        for compiled in (True, False):
            paced = np.percentile(run(args.joints, args.samples, velocities, compiled, True),
                                  [50, 90, 99])
            loop = np.percentile(run(args.joints, args.samples, velocities, compiled, False),
                                 [50, 90])
            print(f"| {'with velocities' if velocities else 'positions only'} | "
                  f"{'compiled' if compiled else 'Python'} | "
                  f"{paced[0]:.1f} / {paced[1]:.1f} / {paced[2]:.1f} | {loop[0]:.1f} / {loop[1]:.1f} |")
    print(f"load average {os.getloadavg()[0]:.2f} at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
