"""check_bag: is a recorded run right? Pipeline error, model error, delivery, in one table.

    check_bag BAG [--json OUT] [--thresholds config/check.yaml] [--reference FILE]
    check_bag BAG --recover OUT

Exit codes: 0 all thresholds met; 1 a threshold exceeded (each failure named: movement,
DOF, value); 2 the bag cannot be analysed (missing, empty, not MCAP, truncated before the
first complete chunk, a damaged chunk in an indexed bag, no joint_torques, torques without
the model's joints, markers of no known movement): one line, no traceback.
A truncated bag that still holds data is analysed, with a warning. A bag without movement
markers (any recording) is scored as one segment against its own filtered positions
(bag/score.py); `--baseline OLD` compares two runs' torques (bag/regression.py).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from ..bag import BagError, open_bag, recover
from ..bag.check import CheckReport, Thresholds, analyse
from ..bag.decode import read_config, read_recording
from ..bag.model_config import model_from_config
from ..movements import get_movement, movement_library
from ..reference import ReferenceTorques, load_reference, read_reference
from .common import die

PROG = "check_bag"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    ap.add_argument("bag", type=Path, help="MCAP file written by bag_recorder (or ros2 bag)")
    ap.add_argument("--json", type=Path, metavar="OUT", help="write the full report as JSON")
    ap.add_argument("--thresholds", type=Path, metavar="YAML",
                    help="thresholds (default: the package's config/check.yaml)")
    ap.add_argument("--reference", type=Path, metavar="NPZ",
                    help="reference torques file (default: the shipped one)")
    ap.add_argument("--recover", type=Path, metavar="OUT",
                    help="rewrite a truncated bag as a complete one into OUT, then exit")
    ap.add_argument("--baseline", type=Path, metavar="OLD",
                    help="regression: compare joint_torques with OLD's, stamp by stamp")
    ap.add_argument("--tolerance", type=float, default=1e-6, metavar="NM",
                    help="with --baseline: largest allowed |difference| (N·m, default 1e-6)")
    return ap.parse_args(argv)


def _known_movement(movement_id: int) -> bool:
    try:
        get_movement(movement_id)
    except (ValueError, KeyError, IndexError):
        return False
    return True


def _reference(path: Path | None) -> tuple[ReferenceTorques | None, str | None]:
    try:
        return (read_reference(path) if path else load_reference()), None
    except (OSError, ValueError, KeyError) as exc:
        return None, f"reference torques unavailable ({exc})"


def _num(x: float, fmt: str = ".4f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, fmt)


def _clean(obj):
    """JSON-safe: numpy -> lists, NaN/inf -> None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def to_json(report: CheckReport, bag_info, th: Thresholds, code: int) -> dict:
    names = report.joint_names
    d = report.delivery
    return _clean({
        "bag": {"path": str(bag_info.path), "complete": bag_info.complete, "problem": bag_info.problem,
                "messages": bag_info.message_count, "topics": bag_info.topic_counts()},
        "model": {"kind": report.model.arm.kind, "body_size": report.model.arm.body_size.label,
                  "source": report.model.source},
        "joint_names": list(names),
        "movements": [{
            "index": r.index, "id": r.id, "name": r.name, "elbow": r.elbow, "t0_ns": r.t0_ns,
            "samples": r.samples, "expected": r.expected,
            "state_error_rad": r.state_error, "state_dof": r.state_dof,
            "pipeline_nrmse": dict(zip(names, r.pipeline_nrmse, strict=True)),
            "pipeline_worst": dict(zip(("nrmse", "dof"), r.worst(r.pipeline_nrmse, names), strict=True)),
            "pipeline_left_out": r.pipeline_left_out,
            "model_nrmse": None if r.model_nrmse is None else dict(zip(names, r.model_nrmse, strict=True)),
            "model_worst": dict(zip(("nrmse", "dof"), r.worst(r.model_nrmse, names), strict=True)),
            "model_note": r.model_note,
        } for r in report.movements],
        "model_error_groups": report.model_groups,
        "delivery": {
            "joint_states": d.joint_states, "joint_torques": d.joint_torques,
            "considered": d.considered, "lost": d.lost, "loss_pct": d.loss_pct,
            "unmatched_torques": d.unmatched_torques, "latency_ms": d.latency_ms,
            "rate_hz": d.rate_hz, "max_gap_ms": d.max_gap_ms,
        },
        "thresholds": th.__dict__,
        "warnings": report.warnings,
        "failures": report.failures,
        "exit_code": code,
    })


def print_report(report: CheckReport, bag_info, out=None) -> None:
    out = out or sys.stdout
    names = report.joint_names
    p = lambda *a: print(*a, file=out)
    p(f"{bag_info.path}: {bag_info.message_count} messages, {len(report.movements)} movements; "
      f"model {report.model.describe()}")
    for w in report.warnings:
        p(f"warning: {w}")
    p(f"{'id':>3} {'name':<32} {'elbow':<16} {'n':>5} {'state rad':>9}  {'pipeline NRMSE':>14} "
      f"{'(DOF)':<20} {'model NRMSE':>11} (DOF)")
    for r in report.movements:
        pv, pd = r.worst(r.pipeline_nrmse, names)
        mv, md = r.worst(r.model_nrmse, names)
        p(f"{r.id:>3} {r.name[:32]:<32} {r.elbow[:16]:<16} {r.samples:>5} {_num(r.state_error, '.1e'):>9}"
          f"  {_num(pv):>14} {pd:<20} {_num(mv):>11} {md}")
    if report.model_groups:
        p("model NRMSE by DOF group (RMSE / largest reference peak-to-peak; median / max): " + ", ".join(
            f"{g} {_num(s['median'], '.3f')}/{_num(s['max'], '.3f')}"
            for g, s in report.model_groups.items()))
    d = report.delivery
    lat = d.latency_ms
    p(f"delivery: joint_states {d.joint_states} ({_num(d.rate_hz.get('joint_states', math.nan), '.1f')} Hz), "
      f"joint_torques {d.joint_torques} ({_num(d.rate_hz.get('joint_torques', math.nan), '.1f')} Hz); "
      f"lost {d.lost} of {d.considered} ({_num(d.loss_pct, '.3f')} %); latency p50 "
      f"{_num(lat.get('p50', math.nan), '.3f')} ms, p99 {_num(lat.get('p99', math.nan), '.3f')} ms, "
      f"max {_num(lat.get('max', math.nan), '.3f')} ms")
    for f in report.failures:
        p(f"FAIL: {f}")
    p("PASS" if not report.failures else f"FAIL ({len(report.failures)} threshold(s) exceeded)")


def _recover(src: Path, dst: Path) -> int:
    res = recover(src, dst)
    state = "complete" if res.source_complete else f"damaged: {res.problem}"
    counts = ", ".join(f"{t} {n}" for t, n in res.counts.items())
    print(f"{PROG}: recovered {res.messages} messages ({counts}) from {src} ({state}) into {dst}")
    return 0


def _regression(args: argparse.Namespace) -> int:
    from ..bag import regression

    rep = regression.compare(args.bag, args.baseline, args.tolerance)
    code = 1 if rep.failures else 0
    print("\n".join(regression.format_report(rep)))
    if args.json is not None:
        args.json.write_text(json.dumps({**regression.to_dict(rep), "exit_code": code}, indent=1),
                             encoding="utf-8")
    return code


def _markerless(args: argparse.Namespace, rec, choice, th: Thresholds, info) -> int:
    from ..bag import score

    if rec.joint_states is None or len(rec.joint_states) == 0:
        raise BagError("foreign", f"{args.bag}: no movement markers and no joint_states: "
                       "nothing to compute a reference from")
    if not info.complete:
        rec.warnings.insert(0, f"bag is truncated ({info.problem}); analysing the "
                            f"{info.message_count} messages of its complete chunks")
    report = score.analyse_markerless(rec, choice, th)
    code = 1 if report.failures else 0
    print("\n".join(score.format_score(report, info)))
    if args.json is not None:
        args.json.write_text(json.dumps({**score.score_dict(report), "exit_code": code}, indent=1),
                             encoding="utf-8")
    return code


def run(args: argparse.Namespace) -> int:
    if args.recover is not None:
        return _recover(args.bag, args.recover)
    if args.baseline is not None:
        return _regression(args)
    th = Thresholds.load(args.thresholds)
    bag = open_bag(args.bag)
    info = bag.info
    if info.message_count == 0:
        raise BagError("no_data", f"{args.bag}: no messages"
                       + (f" recovered ({info.problem})" if info.problem else ""))
    torques_ch = info.find_topic("joint_torques")
    if torques_ch is None:
        raise BagError("foreign", f"{args.bag}: no joint_torques topic (topics: "
                       f"{', '.join(sorted(info.topic_counts())) or 'none'}); not a forearm_dynamics run")
    if info.counts.get(torques_ch.id, 0) == 0:
        why = f"truncated ({info.problem}) before its first complete chunk with joint_torques" \
            if not info.complete else "joint_torques was recorded but holds no message"
        raise BagError("no_data", f"{args.bag}: {why}")
    # The config first (it names the model, hence the joint order), then one pass for the rest.
    config, config_warnings = read_config(bag)
    try:
        choice = model_from_config(config)
    except (ValueError, TypeError, KeyError) as exc:
        raise BagError("foreign", f"{args.bag}: torque_node/config names a model that cannot be "
                       f"built ({exc})") from None
    rec = read_recording(bag, choice.arm.joint_names)
    rec.warnings[:0] = config_warnings
    if not rec.markers:  # any recording (a subject's session): scored as one segment
        return _markerless(args, rec, choice, th, info)
    if not any(_known_movement(m.id) for m in rec.markers):
        ids = sorted({m.id for m in rec.markers})
        raise BagError("foreign", f"{args.bag}: no movement marker names a known movement (ids "
                       f"{ids[:5]}{' ...' if len(ids) > 5 else ''}; known 1..{len(movement_library())})")
    if not np.isfinite(rec.joint_torques.effort).all(axis=1).any():
        raise BagError("foreign", f"{args.bag}: no joint_torques message carries an effort for every "
                       f"joint of the {choice.arm.kind} model; not this model's torques")
    if not info.complete:
        rec.warnings.insert(0, f"bag is truncated ({info.problem}); analysing the "
                            f"{info.message_count} messages of its complete chunks")
    ref, ref_problem = _reference(args.reference)
    report = analyse(rec, choice, ref, th, ref_problem)
    code = 1 if report.failures else 0
    try:
        print_report(report, info)
        sys.stdout.flush()
    except BrokenPipeError:  # `check_bag BAG | head`: the reader left; keep the exit code
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    if args.json is not None:
        args.json.write_text(json.dumps(to_json(report, info, th, code), indent=1), encoding="utf-8")
    return code


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        return run(args)
    except BagError as exc:
        return die(f"{PROG}: error: {exc}")
    except (OSError, ValueError) as exc:
        return die(f"{PROG}: error: {exc}")
    except Exception as exc:  # noqa: BLE001 - a bad file must never end in a traceback
        return die(f"{PROG}: error: {args.bag}: cannot analyse ({type(exc).__name__}: {exc})")


if __name__ == "__main__":
    sys.exit(main())
