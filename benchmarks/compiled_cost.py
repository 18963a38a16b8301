"""The Kalman filter's compiled parts against Python's, per sample: paced like a node at
1 kHz, and back to back.

    .venv/bin/python benchmarks/compiled_cost.py [--part noise|gains|practice|all] [--samples 6000]

Why paced: a node sleeps ~0.9 ms between samples and each call then runs on cold caches, so
a loop's back-to-back figure understates what the node pays several times over (docs/
performance.md). Each case feeds a 1 kHz stream with ±10 % stamp jitter (a publisher's
clock), a slow movement plus 0.06° noise on every joint, positions only or with velocities,
once compiled and once in Python (the reference each compiled part replaces); the first
1 000 samples are discarded. Parts: `noise`, the noise estimator's add() (the compiled
store and the evaluations it makes due, estimation/noise_step.py); `gains`, the noise
groups' covariance step inside the filter's update() (the compiled Gains,
estimation/noise_groups.py), with update() itself; `practice`, update() on positions with
0.3° of coloured noise, where the practice filter runs on every joint (the compiled
Practice, estimation/practice_step.py).
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


def stream(joints: int, samples: int, coloured: float = 0.0):
    """(stamp ns, q, qd) at 1 kHz with ±10 % jitter: a slow movement plus noise (and, with
    `coloured` > 0, that std (rad) of first-order noise with a 20 ms correlation time: the
    practice filter's joints); q and qd are the same arrays every sample (a node's message
    buffers)."""
    rng = np.random.default_rng(0)
    q, qd, c = np.zeros(joints), np.zeros(joints), np.zeros(joints)
    a = np.exp(-1e-3 / 0.02)
    t_ns = 10**18
    for k in range(samples):
        t_ns += 1_000_000 + int(rng.integers(-100_000, 100_000))
        if coloured:
            c[:] = a * c + rng.normal(0.0, coloured * np.sqrt(1.0 - a * a), joints)
        q[:] = np.sin(k * 1e-3) + rng.normal(0.0, 1e-3, joints) + c
        qd[:] = np.cos(k * 1e-3) + rng.normal(0.0, 1e-2, joints)
        yield t_ns, q, qd


def _us(times_ns: list[int]) -> np.ndarray:
    """The times after the warm-up, in µs."""
    return np.array(times_ns[WARMUP:]) / 1e3


def timed_calls(call, joints: int, samples: int, velocities: bool, paced: bool,
                after=None, coloured: float = 0.0) -> np.ndarray:
    """call(t_ns, q, qd or None) on each sample of the stream, timed (µs after the warm-up);
    after(), if given, runs after each call, not timed."""
    clock, out = time.perf_counter_ns, []
    for t_ns, q, qd in stream(joints, samples, coloured):
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


def run_practice(joints: int, samples: int, compiled: bool, paced: bool) -> tuple[np.ndarray, float]:
    """KalmanCA.update per sample (µs), positions only with 0.3° of coloured noise (the
    practice filter on every joint: practice_output.py), learn() after each as the node calls
    it, not timed; and the filter's share at the end (1: it ran)."""
    est = make_estimator("kalman", joints)
    if not compiled:
        est.python_practice()
    whole = timed_calls(est.update, joints, samples, False, paced, after=est.learn,
                        coloured=np.radians(0.3))
    return whole, float(est.practice_filter_weight().min())


def _row(*cells) -> str:
    return "| " + " | ".join(cells) + " |"


def _pct(x: np.ndarray, q=(50, 90, 99)) -> str:
    return " / ".join(f"{v:.1f}" for v in np.percentile(x, q))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--part", choices=("noise", "gains", "practice", "all"), default="all")
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
    if args.part in ("practice", "all"):
        print("\nupdate() with the practice filter, positions only, 0.3° coloured noise:\n")
        print(_row("practice filter", "paced p50 / p90 / p99 µs", "back to back p50 / p90 µs",
                   "filter's share"))
        print(_row(*["---"] * 4))
        for compiled in (True, False):
            paced, share = run_practice(args.joints, args.samples, compiled, True)
            loop, _ = run_practice(args.joints, args.samples, compiled, False)
            print(_row("compiled" if compiled else "Python", _pct(paced), _pct(loop, (50, 90)),
                       f"{share:g}"))
    print(f"\nload average {os.getloadavg()[0]:.2f} at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
