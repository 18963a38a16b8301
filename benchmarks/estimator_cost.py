"""The estimators' update() cost, alone (no node, no DDS): p50 / p99 / max per call.

    .venv/bin/python benchmarks/estimator_cost.py [--seconds 200] [--joints 20]

Streams: 1 kHz with velocities (what the node benchmark streams) and 100 Hz positions only
(a mocap file), a 0.7 Hz movement on every joint through 0.3 deg (1 deg/s) white noise, the
first tenth discarded; the default settings, with delay_s 0.05, positions only with issue 29's
practice filter off (the model alone: what the filter costs) and the causal Butterworth for
scale. The p99 of a positions-only stream is its noise
updates (every 0.25 s: 4 % of the samples at 100 Hz): the regroups, and any Riccati solve
that seats a group there (ca_model.steady_posterior, cached since issue 29 item 5). Timing:
noisy on a shared machine; state `uptime` with the numbers.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from forearm_dynamics.estimation import make_estimator

CASES = (("1 kHz, velocities, default", 1000.0, True, {}),
         ("100 Hz, positions, default", 100.0, False, {}),
         ("100 Hz, positions, practice filter off", 100.0, False, {"practice_filter": 0.0}),
         ("1 kHz, velocities, delay 0.05 s", 1000.0, True, {"delay_s": 0.05}),
         ("100 Hz, positions, delay 0.05 s", 100.0, False, {"delay_s": 0.05}),
         # the delayed estimate's practice blend (practice_lag.py) against the model's smoother
         ("100 Hz, positions, delay 0.05 s, model smoother only", 100.0, False,
          {"delay_s": 0.05, "delay_practice_hz": 0.0}),
         ("1 kHz, positions, delay 0.05 s", 1000.0, False, {"delay_s": 0.05}),
         ("1 kHz, positions, delay 0.05 s, model smoother only", 1000.0, False,
          {"delay_s": 0.05, "delay_practice_hz": 0.0}),
         ("1 kHz, positions, default", 1000.0, False, {}),
         ("1 kHz, positions, practice filter off", 1000.0, False, {"practice_filter": 0.0}),
         ("100 Hz, positions, butterworth", 100.0, False, {"estimator": "butterworth"}))


def run(rate: float, vel: bool, settings: dict, seconds: float, n: int) -> np.ndarray:
    """Per-call update() times (µs) after the first tenth."""
    rng = np.random.default_rng(1)
    m = round(seconds * rate)
    t = np.arange(m) / rate
    phase = 2 * np.pi * 0.7 * t[:, None] + np.arange(n)
    q = 0.5 * np.sin(phase) + math.radians(0.3) * rng.standard_normal((m, n))
    qd = 0.5 * 2 * np.pi * 0.7 * np.cos(phase) + math.radians(1.0) * rng.standard_normal((m, n))
    settings = dict(settings)
    est = make_estimator(settings.pop("estimator", "kalman"), n, settings)
    stamps = np.round(t * 1e9).astype(np.int64) + 10**9
    out = np.empty(m)
    for k in range(m):
        a = time.perf_counter_ns()
        est.update(int(stamps[k]), q[k], qd[k] if vel else None)
        out[k] = time.perf_counter_ns() - a
    return out[m // 10:] / 1e3


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=200.0, help="stream length at 100 Hz (1 kHz: a tenth)")
    ap.add_argument("--joints", type=int, default=20)
    args = ap.parse_args(argv)
    for what, rate, vel, settings in CASES:
        try:
            d = run(rate, vel, settings, args.seconds * 100.0 / rate, args.joints)
        except ValueError as exc:  # an estimator without the option (an older checkout)
            print(f"{what}: {exc}")
            continue
        print(f"{what}: update() p50 {np.median(d):.1f} µs, p99 {np.percentile(d, 99):.1f} µs, "
              f"max {d.max():.0f} µs ({len(d)} calls)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
