"""The closed-loop example's results (examples/closed_loop.py): per movement the tracking
error against the library movement, the loop's latencies, results.json, tracking.npz and
the plot. Beside closed_loop.py (installed with it), which imports it."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np

from forearm_dynamics import JOINT_NAMES, get_movement


def tracking(ctrl) -> list[dict]:
    """Per movement: RMS and max error per joint after hold_before, from the markers; in
    lockstep also how many steps after hold_before went without the reference of their time
    unnoticed (the tracking error is the loop's own only when that is 0), how many waited
    out WAIT_S first (a reference lost: counted, the loop goes on), and how late (simulated
    time) the marker came."""
    stamps = np.array([s for s, _ in ctrl.states], dtype=np.int64)
    qs = np.array([q for _, q in ctrl.states])
    steps = np.array(ctrl.steps_ref, dtype=np.int64).reshape(-1, 3)
    out = []
    for mk in ctrl.markers:
        mv = get_movement(mk["id"])
        t = (stamps - mk["t0_ns"]) / 1e9
        sel = (t >= mv.hold_before) & (t < mv.duration)
        if sel.sum() < 100:
            continue
        q_ref, _, _ = mv.evaluate(t[sel])
        err = qs[sel] - q_ref
        ts = (steps[:, 0] - mk["t0_ns"]) / 1e9
        behind = (ts >= mv.hold_before) & (ts < mv.duration) & (steps[:, 1] < steps[:, 0])
        stale = behind & (steps[:, 2] == 1)
        behind &= ~stale
        extra = {"steps_behind": int(behind.sum()), "stale_steps": int(stale.sum()),
                 "max_behind_ms": float((steps[behind, 0] - steps[behind, 1]).max() / 1e6)
                 if behind.any() else 0.0,
                 "marker_late_ms": (mk["seen_at_ns"] - mk["t0_ns"]) / 1e6} if ctrl.lockstep else {}
        out.append({"id": mv.id, "name": mv.name, "elbow": mv.elbow, "samples": int(sel.sum()),
                    **extra,
                    "rms_rad": dict(zip(JOINT_NAMES, np.sqrt((err**2).mean(0)).tolist(), strict=True)),
                    "max_rad": dict(zip(JOINT_NAMES, np.abs(err).max(0).tolist(), strict=True)),
                    "t": t[sel].tolist(), "q_sim": qs[sel].tolist(), "q_ref": q_ref.tolist()})
    return out


def _pct(ns: list[int]) -> str:
    if not ns:
        return "none"
    p50, p99 = np.percentile(np.asarray(ns) / 1e6, [50, 99])
    return f"p50 {p50:.2f} ms, p99 {p99:.2f} ms (n={len(ns)})"


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    joints = ("elbow_flexion", "pro_sup", "wrist_flexion", "index_mcp_flexion")
    fig, axes = plt.subplots(len(joints), len(results), figsize=(4 * len(results), 9),
                             squeeze=False, sharex=True)
    for c, r in enumerate(results):
        t = np.asarray(r["t"])
        for k, j in enumerate(joints):
            i = JOINT_NAMES.index(j)
            ax = axes[k][c]
            ax.plot(t, np.degrees(np.asarray(r["q_ref"])[:, i]), "k-", lw=2, label="reference")
            ax.plot(t, np.degrees(np.asarray(r["q_sim"])[:, i]), "r--", lw=1.2, label="arm_sim")
            ax.set_ylabel(f"{j} (deg)")
            if k == 0:
                ax.set_title(f"movement {r['id']}: {r['name']}\nRMS {r['rms_rad'][j]:.2g} rad",
                             fontsize=9)
            else:
                ax.set_title(f"RMS {r['rms_rad'][j]:.2g} rad", fontsize=9)
        axes[-1][c].set_xlabel("time in movement (s)")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def report(ctrl, args, movements, out: Path, wait_s: float) -> int:
    """Print and write the tracking error and latencies; 0 when every movement was tracked."""
    results = tracking(ctrl)
    mode = "PD only" if args.no_feedforward else "feed-forward (torque_node) + PD"
    print(f"closed loop, {mode}, arm_sim {'lockstep' if args.lockstep else '1 kHz real time'}; "
          f"load average "
          f"{os.getloadavg()[0]:.2f} (2 cores)")
    for r in results:
        rms, mx = r["rms_rad"], r["max_rad"]
        worst = max(rms, key=rms.get)
        print(f"movement {r['id']:2d} ({r['name']}, {r['elbow']}): tracking RMS elbow "
              f"{rms['elbow_flexion']:.2e}, pro_sup {rms['pro_sup']:.2e}, wrist "
              f"{rms['wrist_flexion']:.2e} rad; worst joint {worst} RMS {rms[worst]:.2e}, "
              f"max {mx[worst]:.2e} rad")
        if args.lockstep:
            print(f"  lockstep: marker {r['marker_late_ms']:.0f} ms (simulated) after the start; "
                  f"after the hold {r['steps_behind']} step(s) ran ahead of their reference "
                  f"unnoticed (at most {r['max_behind_ms']:.0f} ms), {r['stale_steps']} waited "
                  f"it out")
    print(f"loop latency (command -> applied state back): {_pct(ctrl.loop_ns)}")
    if args.lockstep:
        print(f"lockstep: {len(ctrl.states)} steps, {ctrl.stale_steps} without the reference of "
              f"their time (waited > {wait_s:g} s)")
    if not args.lockstep:  # (lockstep: the stamps are simulated time)
        print(f"feed-forward latency (reference stamp -> torque received): {_pct(ctrl.ff_ns)}")
    summary = {"mode": mode, "movements": [{k: v for k, v in r.items() if k not in ("t", "q_sim", "q_ref")}
                                           for r in results],
               "loop_latency_ms": (np.percentile(np.asarray(ctrl.loop_ns) / 1e6, [50, 99]).tolist()
                                   if ctrl.loop_ns else None),
               "ff_latency_ms": (np.percentile(np.asarray(ctrl.ff_ns) / 1e6, [50, 99]).tolist()
                                 if ctrl.ff_ns and not args.lockstep else None),
               "lockstep": args.lockstep, "steps": len(ctrl.states),
               "stale_steps": ctrl.stale_steps,
               "loadavg": list(os.getloadavg())}
    (out / "results.json").write_text(json.dumps(summary, indent=1))
    np.savez(out / "tracking.npz", stamps=np.array([t for t, _ in ctrl.states], dtype=np.int64),
             q=np.array([q for _, q in ctrl.states]), markers=json.dumps(ctrl.markers))
    if args.plot:
        plot(results, out / "closed_loop.png")
        print(f"plot: {out / 'closed_loop.png'}")
    print(f"results: {out / 'results.json'}")
    if len(results) != len(movements):
        print(f"closed_loop: {len(results)} of {len(movements)} movements were tracked",
              file=sys.stderr)
        return 2
    return 0
