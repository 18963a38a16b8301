"""How much the horizon's growth matters for the σ of an extrapolated output (torque_node's
output_rate_hz > 0; docs/uncertainty.md "Timer output"). No ROS: the node's estimator and
TorqueStd, offline.

    .venv/bin/python benchmarks/uncertainty_prediction.py [--rate 100] [--outputs 5]

Four library movements (3, 20, 37, 54) after a 0.5 s held lead, sampled at --rate with
0.5 deg noise; after each warm sample, --outputs extrapolations spread over the interval to
the next one (plus 0.3 ms, a loopback delivery), where the σ is known. Each is scored against the noiseless
truth at its stamp (model part left out: the truth is the same model): coverage of ±1.96σ
and RMS(σ)/RMSE for the prediction σ (TorqueStd.predict), for the σ of the estimate it
starts from (h = 0: no growth) and for the prediction σ without the lag part.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from forearm_dynamics import build_model
from forearm_dynamics.estimation import make_estimator
from forearm_dynamics.movements import movement_library
from forearm_dynamics.uncertainty import TorqueStd

MOVEMENTS = (3, 20, 37, 54)
LEAD = 50


def run(rate: float, outputs: int) -> dict[str, tuple[float, float, int]]:
    arm = build_model()
    lib = movement_library()
    rng = np.random.default_rng(19)
    res: dict[str, list] = {"prediction": [], "no_growth": [], "prediction_no_lag": []}
    for i in MOVEMENTS:
        mv = lib[i]
        t = np.concatenate([np.arange(-LEAD, 0) / rate, mv.sample_times(rate)])
        q = mv.evaluate(t)[0]
        z = q + rng.normal(0.0, math.radians(0.5), q.shape)
        est = make_estimator("kalman", arm.nv)
        ts, ts_nolag = TorqueStd(arm, est), TorqueStd(arm, est, lag=False)
        for k in range(len(t) - 1):
            t_ns = round((t[k] + 10.0) * 1e9)
            warm = est.update(t_ns, z[k], None)
            ts.observe(est.stamp_ns, False)
            ts_nolag.observe(est.stamp_ns, False)
            if not warm or k < LEAD + 10:
                continue
            for j in range(outputs):
                h = (j + 0.5) / outputs / rate + 3e-4
                s_ns = t_ns + round(h * 1e9)
                est.predict(s_ns)
                truth = arm.inverse_dynamics(*(x[0] for x in mv.evaluate(np.array([t[k] + h]))))
                err = np.abs(arm.inverse_dynamics(est.q, est.qd, est.qdd) - truth)
                sds = {}
                for name, tsx, at in (("prediction", ts, s_ns), ("prediction_no_lag", ts_nolag, s_ns),
                                      ("no_growth", ts, t_ns)):
                    if not tsx.predict(at):  # σ not known yet (the noise not measured)
                        break
                    sds[name] = np.sqrt(np.maximum(tsx.std**2 - ts.model_var, 0.0))
                else:
                    for name, sd in sds.items():
                        res[name].append((err, sd))
    out = {}
    for name, rows in res.items():
        e = np.array([r[0] for r in rows])
        s = np.array([r[1] for r in rows])
        out[name] = (float(np.mean(e <= 1.96 * s)), float(np.sqrt(np.mean(s**2) / np.mean(e**2))), len(e))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rate", type=float, default=100.0, help="input rate (Hz)")
    ap.add_argument("--outputs", type=int, default=5, help="extrapolations per input interval")
    args = ap.parse_args(argv)
    for name, (cover, ratio, n) in run(args.rate, args.outputs).items():
        print(f"{args.rate:g} Hz {name:18s} coverage {cover:.3f}  RMS(σ)/RMSE {ratio:.2f}  "
              f"({n} outputs x 20)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
