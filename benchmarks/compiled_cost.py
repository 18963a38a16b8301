"""The Kalman filter's compiled parts against Python's, per sample: paced like a node at
1 kHz, and back to back.

    .venv/bin/python benchmarks/compiled_cost.py [--part noise|gains|all] [--samples 6000]

Why paced: a node sleeps ~0.9 ms between samples and each call then runs on cold caches, so
a loop's back-to-back figure understates what the node pays several times over (docs/
performance.md). Each case feeds a 1 kHz stream with ±10 % stamp jitter (a publisher's
clock), a slow movement plus 0.06° noise on every joint, positions only or with velocities,
once compiled and once in Python (the reference each compiled part replaces); the first
1 000 samples are discarded. Parts: `noise`, the noise estimator's add() (the compiled
store and the evaluations it makes due, estimation/noise_step.py); `gains`, the noise
groups' covariance step inside the filter's update() (the compiled Gains,
estimation/noise_groups.py), with update() itself.
Prints p50 / p90 / p99 in µs. Timing is noisy on a shared machine: state `uptime` with the
numbers.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from forearm_dynamics.estimation import make_estimator
from forearm_dynamics.estimation.noise import NoiseEstimator

WARMUP = 1000


def stream(joints: int, samples: int):
    """(stamp ns, q, qd) at 1 kHz with ±10 % jitter: a slow movement plus noise; q and qd are
    the same arrays every sample (a node's message buffers)."""
    rng = np.random.default_rng(0)
    q, qd = np.zeros(joints), np.zeros(joints)
    t_ns = 10**18
    for k in range(samples):
        t_ns += 1_000_000 + int(rng.integers(-100_000, 100_000))
        q[:] = np.sin(k * 1e-3) + rng.normal(0.0, 1e-3, joints)
        qd[:] = np.cos(k * 1e-3) + rng.normal(0.0, 1e-2, joints)
        yield t_ns, q, qd


def _us(times_ns: list[int]) -> np.ndarray:
    """The times after the warm-up, in µs."""
    return np.array(times_ns[WARMUP:]) / 1e3


def timed_calls(call, joints: int, samples: int, velocities: bool, paced: bool,
                after=None) -> np.ndarray:
    """call(t_ns, q, qd or None) on each sample of the stream, timed (µs after the warm-up);
    after(), if given, runs after each call, not timed."""
    clock, out = time.perf_counter_ns, []
    for t_ns, q, qd in stream(joints, samples):
        if paced:
            time.sleep(0.0009)
        t = clock()
        call(t_ns, q, qd if velocities else None)
        out.append(clock() - t)
        if after is not None:
            after()
    return _us(out)


def run_noise(joints: int, samples: int, velocities: bool, compiled: bool,
              paced: bool) -> np.ndarray:
    """NoiseEstimator.add per sample (µs)."""
    est = NoiseEstimator(joints) if compiled else NoiseEstimator(joints).python_store()
    return timed_calls(est.add, joints, samples, velocities, paced)


def run_gains(joints: int, samples: int, velocities: bool, compiled: bool,
              paced: bool) -> tuple[np.ndarray, np.ndarray]:
    """The groups' covariance step and the whole KalmanCA.update per sample (µs); learn()
    after each, as the node calls it, not timed."""
    est = make_estimator("kalman", joints)
    if not compiled:
        est.python_gains()
    step, clock, part = est._covariance_step, time.perf_counter_ns, []

    def timed(*args):
        t = clock()
        step(*args)
        part.append(clock() - t)

    est._covariance_step = timed
    whole = timed_calls(est.update, joints, samples, velocities, paced, after=est.learn)
    return _us(part), whole


def _row(*cells) -> str:
    return "| " + " | ".join(cells) + " |"


def _pct(x: np.ndarray, q=(50, 90, 99)) -> str:
    return " / ".join(f"{v:.1f}" for v in np.percentile(x, q))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--part", choices=("noise", "gains", "all"), default="all")
    ap.add_argument("--samples", type=int, default=6000)
    ap.add_argument("--joints", type=int, default=20)
    args = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.2f}; {args.joints} joints, 1 kHz ±10 % jitter")
    inputs = ((False, "positions only"), (True, "with velocities"))
    if args.part in ("noise", "all"):
        print("\nThe noise estimator's add():\n")
        print(_row("input", "store", "paced p50 / p90 / p99 µs", "back to back p50 / p90 µs"))
        print(_row(*["---"] * 4))
        for velocities, name in inputs:
            for compiled in (True, False):
                paced = run_noise(args.joints, args.samples, velocities, compiled, True)
                loop = run_noise(args.joints, args.samples, velocities, compiled, False)
                print(_row(name, "compiled" if compiled else "Python", _pct(paced),
                           _pct(loop, (50, 90))))
    if args.part in ("gains", "all"):
        print("\nThe noise groups' covariance step, and update() around it, paced:\n")
        print(_row("input", "groups' step", "step p50 / p90 / p99 µs", "update() p50 / p90 / p99 µs"))
        print(_row(*["---"] * 4))
        for velocities, name in inputs:
            for compiled in (True, False):
                part, whole = run_gains(args.joints, args.samples, velocities, compiled, True)
                print(_row(name, "compiled" if compiled else "Python", _pct(part), _pct(whole)))
    print(f"\nload average {os.getloadavg()[0]:.2f} at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
