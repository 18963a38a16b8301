"""Compute floor: our per-sample inverse_dynamics against a bare pin.rnea on the same model."""

from __future__ import annotations

import time

import numpy as np
import pinocchio as pin

from forearm_dynamics import build_model, movement_library

from .stats import percentiles


def per_sample(kind: str = "segmented", n: int = 20000, seed: int = 0) -> dict:
    """Alternate our call and the bare call sample by sample, so both see the same machine."""
    model = build_model(kind)
    pm, data = model.model, model.model.createData()
    rng = np.random.default_rng(seed)
    qs = rng.uniform(-1, 1, (n, 3, model.nv))
    ours = np.empty(n)
    bare = np.empty(n)
    clock = time.perf_counter_ns
    for k in range(200):  # warm-up
        model.inverse_dynamics(qs[k, 0], qs[k, 1], qs[k, 2])
        pin.rnea(pm, data, qs[k, 0], qs[k, 1], qs[k, 2])
    for k in range(n):
        q, qd, qdd = qs[k]
        if k % 2:
            t0 = clock()
            pin.rnea(pm, data, q, qd, qdd)
            t1 = clock()
            model.inverse_dynamics(q, qd, qdd)
            t2 = clock()
            bare[k], ours[k] = t1 - t0, t2 - t1
        else:
            t0 = clock()
            model.inverse_dynamics(q, qd, qdd)
            t1 = clock()
            pin.rnea(pm, data, q, qd, qdd)
            t2 = clock()
            ours[k], bare[k] = t1 - t0, t2 - t1
    o, b = percentiles(ours, 1e-3), percentiles(bare, 1e-3)
    return {"model": kind, "unit": "us", "inverse_dynamics": o, "bare_rnea": b,
            "ratio_p50": o["p50"] / b["p50"], "ratio_p99": o["p99"] / b["p99"]}


def batch(kind: str = "segmented", rate_hz: float = 1000.0, repeats: int = 3) -> dict:
    """All 65 movements' samples through inverse_dynamics in one (N, 20) call."""
    model = build_model(kind)
    parts = [m.evaluate(m.sample_times(rate_hz)) for m in movement_library()]
    q, qd, qdd = (np.concatenate([p[i] for p in parts]) for i in range(3))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        model.inverse_dynamics(q, qd, qdd)
        times.append(time.perf_counter() - t0)
    best = min(times)
    return {"model": kind, "samples": int(q.shape[0]), "seconds_best": best,
            "seconds_all": times, "samples_per_s": q.shape[0] / best}


def run() -> dict:
    return {"per_sample": per_sample(), "batch": {k: batch(k) for k in ("anatomical", "solid", "segmented")}}


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=1))
