"""The moving shoulder (docs/shoulder.md): torques against OpenSim, and the torque path's cost.

    python -m benchmarks.shoulder [--hamner subject02_running_ik.mot] [--corpus ue_adl.npz] [--latency]
                                  [--movements 1 2 ...] [--out benchmarks/shoulder.json]

engine: elbow and wrist torques (elbow_flexion, pro_sup, wrist_flexion, wrist_deviation)
of the Pinocchio model with a shoulder against OpenSim 4.6 inverse dynamics of the same
bodies with the shoulder's three coordinates free (opensim_engine.OpenSimArm): NRMSE % =
RMSE / the reference's peak-to-peak, per DOF, worst over the set; on
- the 65 library movements (200 Hz, analytic derivatives) with the synthetic shoulder
  motion of each convention (shoulder.SYNTHETIC), and
- a published full-body IK result (--hamner: Hamner et al. subject02 running, OpenSim IK,
  opensim-models Pipelines/Hamner/outputReference/ResultsIK/subject02_running_ik.mot, not
  committed): its arm_flex_r/arm_add_r/arm_rot_r drive the humerus, elbow_flex_r,
  pro_sup_r (offset -90°: their 0 is full supination), wrist_flex_r, wrist_dev_r the arm;
  derivatives of the 6 Hz zero-phase low-passed angles (np.gradient; both engines get the
  same q, qd, qdd). Also stated: how much the shoulder changes the elbow's torque there;
- (--corpus) the UE-ADL recordings with the real shoulder motion the corpus helper derived
  from their markers (benchmarks/corpus/ue_adl.npz of that branch), as MoBL angles.
latency (--latency): the 1 kHz replay through torque_node with shoulder fullbody (the
publisher adds the synthetic shoulder motion) against null_echo_node fed the same stream,
same run (benchmarks/torque_path.py): p50/p99 of receive - stamp, and the ratio.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.filtering import lowpass
from forearm_dynamics.formats.opensim import read_motion
from forearm_dynamics.movements import movement_library
from forearm_dynamics.opensim_engine import OpenSimArm
from forearm_dynamics.shoulder import CONVENTIONS, synthetic_shoulder_motion

from .stats import claim_domain_arg, loadavg, machine_info, write_json

DOFS = ("elbow_flexion", "pro_sup", "wrist_flexion", "wrist_deviation")
RATE = 200.0
#: Hamner full-body coordinates -> (our joint, sign, offset rad): the shipped map's reading
HAMNER_ARM = {"elbow_flex_r": ("elbow_flexion", 1.0, 0.0), "pro_sup_r": ("pro_sup", 1.0, -np.pi / 2),
              "wrist_flex_r": ("wrist_flexion", 1.0, 0.0), "wrist_dev_r": ("wrist_deviation", 1.0, 0.0)}


def nrmse(ours: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Per column: RMSE / the reference's peak-to-peak, %."""
    span = np.ptp(ref, axis=0)
    return 100.0 * np.sqrt(np.mean((ours - ref) ** 2, axis=0)) / np.where(span > 0, span, np.nan)


def _per_dof(values: np.ndarray) -> dict:
    return {d: float(values[JOINT_NAMES.index(d)]) for d in DOFS}


def library(name: str) -> dict:
    arm = build_model(shoulder=name)
    engine = OpenSimArm(arm.tree, arm.shoulder)
    worst = np.zeros(20)
    t_ours = t_ref = 0.0
    n = 0
    for mv in movement_library():
        t = np.arange(round(mv.duration * RATE)) / RATE
        q, qd, qdd = mv.evaluate(t)
        s, sd, sdd = synthetic_shoulder_motion(name, t)
        Q, V, A = np.hstack([q, s]), np.hstack([qd, sd]), np.hstack([qdd, sdd])
        t0 = time.perf_counter()
        ours = arm.inverse_dynamics(Q, V, A)
        t1 = time.perf_counter()
        ref = engine.inverse_dynamics(Q, V, A)
        t_ours += t1 - t0
        t_ref += time.perf_counter() - t1
        worst = np.fmax(worst, nrmse(ours[:, :20], ref[:, :20]))
        n += len(t)
    return {"movements": len(movement_library()), "samples": n, "rate_hz": RATE,
            "nrmse_pct_worst_movement": _per_dof(worst),
            "pinocchio_us_per_sample": 1e6 * t_ours / n, "opensim_us_per_sample": 1e6 * t_ref / n}


def hamner(path: Path) -> dict:
    m = read_motion(path)
    scale = np.pi / 180.0 if m.in_degrees else 1.0
    col = {lab: m.data[:, i] * scale for i, lab in enumerate(m.labels)}
    fs = 1.0 / float(np.median(np.diff(m.time)))
    n = len(m.time)
    q = np.zeros((n, 23))
    for c, (j, sign, off) in HAMNER_ARM.items():
        q[:, JOINT_NAMES.index(j)] = sign * col[c] + off
    for k, c in enumerate(CONVENTIONS["fullbody"].aliases["right"]):
        q[:, 20 + k] = col[c]
    q = lowpass(q, fs, 6.0)
    qd = np.gradient(q, m.time, axis=0)
    qdd = np.gradient(qd, m.time, axis=0)
    arm = build_model(shoulder="fullbody")
    ours = arm.inverse_dynamics(q, qd, qdd)
    ref = OpenSimArm(arm.tree, arm.shoulder).inverse_dynamics(q, qd, qdd)
    welded = build_model().inverse_dynamics(q[:, :20], qd[:, :20], qdd[:, :20])
    e = JOINT_NAMES.index("elbow_flexion")
    z = np.zeros_like(q)
    grav = arm.inverse_dynamics(q, z, z)[:, e]
    grav_welded = build_model().inverse_dynamics(q[:, :20], z[:, :20], z[:, :20])[:, e]
    return {"file": path.name, "rows": n, "rate_hz": fs, "seconds": float(m.time[-1] - m.time[0]),
            "nrmse_pct": _per_dof(nrmse(ours[:, :20], ref[:, :20])),
            "max_abs_diff_nm": _per_dof(np.abs(ours[:, :20] - ref[:, :20]).max(axis=0)),
            "elbow_torque_range_nm": [float(ours[:, e].min()), float(ours[:, e].max())],
            "elbow_change_by_shoulder_max_nm": float(np.abs(ours[:, e] - welded[:, e]).max()),
            "elbow_gravity_nm": {"welded": [float(grav_welded.min()), float(grav_welded.max())],
                                 "moving": [float(grav.min()), float(grav.max())],
                                 "max_change": float(np.abs(grav - grav_welded).max())},
            "elbow_change_by_shoulder_rms_nm": float(np.sqrt(np.mean((ours[:, e] - welded[:, e]) ** 2))),
            "shoulder_range_deg": {c: [float(np.degrees(q[:, 20 + k].min())),
                                       float(np.degrees(q[:, 20 + k].max()))]
                                   for k, c in enumerate(CONVENTIONS["fullbody"].joint_names)}}


def corpus(path: Path) -> dict:
    """UE-ADL recordings with their real shoulder motion (the corpus helper's ue_adl.npz:
    `<name>/q` (N, 20) rad and `<name>/shoulder` (N, 3) ISB Y-X-Y thorax-humerus angles
    (plane, elevation, axial rotation), 100 Hz; manifest.json beside it names the joints of
    `q`; left arms come mirrored, as right-arm angles), read as MoBL angles (shoulder_rot = axial +
    plane: MoBL's third rotation is rotation - plane). Nothing is fitted: every recording."""
    import json

    data = np.load(path)
    manifest = json.loads((path.parent / "manifest.json").read_text())
    recs = manifest if isinstance(manifest, list) else manifest.get("recordings", manifest)
    joints = {r["name"]: r["joints"] for r in (recs if isinstance(recs, list) else recs.values())}
    names = sorted(k[:-len("/shoulder")] for k in data if k.endswith("/shoulder"))
    arm = build_model(shoulder="mobl")
    engine = OpenSimArm(arm.tree, arm.shoulder)
    welded = build_model()
    per, change = [], []
    e = JOINT_NAMES.index("elbow_flexion")
    for name in names:
        sh = data[f"{name}/shoulder"]
        measured = data[f"{name}/q"]  # the manifest's joints, in its order (the left mirrored)
        q = np.zeros((len(sh), 23))
        for c, j in enumerate(joints[name]):
            q[:, JOINT_NAMES.index(j)] = measured[:, c]
        q[:, 20:22] = sh[:, :2]
        q[:, 22] = sh[:, 2] + sh[:, 0]
        if len(q) < 30:
            continue
        t = np.arange(len(q)) / 100.0
        q = lowpass(q, 100.0, 6.0)
        qd = np.gradient(q, t, axis=0)
        qdd = np.gradient(qd, t, axis=0)
        ours = arm.inverse_dynamics(q, qd, qdd)
        per.append(nrmse(ours[:, :20], engine.inverse_dynamics(q, qd, qdd)[:, :20]))
        change.append(float(np.abs(ours[:, e] - welded.inverse_dynamics(q[:, :20], qd[:, :20],
                                                                          qdd[:, :20])[:, e]).max()))
    per = np.array(per)
    return {"file": path.name, "recordings": len(per),
            "nrmse_pct_worst_recording": _per_dof(np.nanmax(per, axis=0)),
            "nrmse_pct_median": _per_dof(np.nanmedian(per, axis=0)),
            "elbow_change_by_shoulder_max_nm_median": float(np.median(change)),
            "elbow_change_by_shoulder_max_nm_max": float(np.max(change))}


def latency(movements: list[int], domain: int) -> dict:
    from .torque_path import Variant, run_variant

    pub = ["-p", "shoulder:=fullbody"]
    out = {}
    with tempfile.TemporaryDirectory(prefix="bench_shoulder_") as tmp:
        for v in (Variant("null_echo", node="null_echo_node", pub_args=pub),
                  Variant("torque_node_shoulder", node_args=["-p", "shoulder:=fullbody"], pub_args=pub),
                  Variant("torque_node_no_shoulder")):
            r = run_variant(v, movements, domain, Path(tmp), start_delay=2.0)
            out[v.name] = {k: r.get(k) for k in ("latency_ms", "lost", "sent", "received",
                                                 "callback_us", "node_process", "foreign_cpu_percent")
                           if k in r}
    try:
        p50 = {k: out[k]["latency_ms"]["p50"] for k in out}
        out["ratio_p50_shoulder_to_null_echo"] = p50["torque_node_shoulder"] / p50["null_echo"]
        out["ratio_p50_no_shoulder_to_null_echo"] = p50["torque_node_no_shoulder"] / p50["null_echo"]
    except (KeyError, TypeError, ZeroDivisionError):
        pass
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks.shoulder", description=__doc__.split("\n\n")[0])
    ap.add_argument("--hamner", type=Path, default=None, help="subject02_running_ik.mot (fetched)")
    ap.add_argument("--corpus", type=Path, default=None,
                    help="the corpus helper's benchmarks/corpus/ue_adl.npz (UE-ADL, real shoulder motion)")
    ap.add_argument("--latency", action="store_true", help="also the torque path (ROS processes)")
    ap.add_argument("--movements", type=int, nargs="+", default=list(range(1, 21)))
    ap.add_argument("--domain", type=int, default=83)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/shoulder.json"))
    args = ap.parse_args(argv)
    given = sys.argv[1:] if argv is None else argv
    result: dict = {"command": "python -m benchmarks.shoulder " + " ".join(given),
                    "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                    "machine": machine_info(), "load_before": loadavg()}
    result["library"] = {name: library(name) for name in CONVENTIONS}
    if args.hamner is not None:
        result["hamner_subject02"] = hamner(args.hamner)
    if args.corpus is not None:
        result["ue_adl"] = corpus(args.corpus)
    if args.latency:
        lease = claim_domain_arg(ap, args.domain, "benchmarks.shoulder")
        try:
            result["latency"] = latency(args.movements, lease.domain)
        finally:
            lease.release()
    result["load_after"] = loadavg()
    write_json(args.out, result)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
