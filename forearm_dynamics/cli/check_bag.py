"""check_bag: is a recorded run right? Pipeline error, model error, delivery, in one table.

    check_bag BAG [--json OUT] [--html REPORT.html] [--thresholds config/check.yaml]
                  [--reference FILE] [--max-latency-p99-ms MS]
                  [--std-coverage LO,HI] [--std-ratio LO,HI] [--cutoff HZ]
    check_bag BAG --recover OUT

Exit codes (forearm_dynamics.exit_codes) mean correctness, not speed:
  0 (OK)    the data are right: every threshold met.
  1 (DATA)  the data are wrong or lost: each failure named (movement, DOF, value; a lost
            message by its stamp; joint_states a movement's marker announced that the bag
            lacks between recorded ones, by movement). Latency fails only when a maximum is asked for
            (--max-latency-p99-ms, or latency_p99_ms_max in the thresholds file; off by
            default): otherwise it is reported against its target with the load average.
  2 (USAGE) the bag cannot be analysed (missing, empty, not MCAP, truncated before the
            first complete chunk, a damaged chunk in an indexed bag, no joint_torques,
            torques without the model's joints, markers of no known
            movement), or a bad argument: one line, no traceback.
A truncated bag that still holds data is analysed, with a warning. A bag without movement
markers (any recording) is scored as one segment against its own filtered positions
(offline/score.py: reported, gated only on loss and non-finite torques; the positions are
low-passed at the practice's 6 Hz, or at 0.4 x the bag's rate when that is lower, said in a
warning: a 10 Hz bag at 4 Hz; `--cutoff HZ` chooses); `--baseline OLD`
compares two runs' torques stamp by stamp (offline/regression.py: exit 1 above --tolerance or
on any unmatched sample).

The --json report (NRMSE values are fractions there: 0.01 = 1 %; times in ms or ns as named):
  bag          path, complete, problem, messages, topics {topic: count}
  model        kind, body_size, side, payload_kg (0 = empty hand), source (where the model
               was read from)
  joint_names  the model's joint order (keys of the per-DOF dicts)
  movements    per movement marker, in bag order: index, id, name, elbow, t0_ns,
               samples (joint_torques in its window), expected, shortfall (why samples <
               expected, or null), inputs_missing (joint_states its marker announced that
               the bag lacks between recorded ones: a failure, as a lost answer is; a
               movement's missing start or end is a note), state_error_rad, state_dof,
               pipeline_nrmse {dof: value},
               pipeline_worst {nrmse, dof}, pipeline_left_out (DOFs under the ptp floor),
               model_nrmse {dof: value} or null, model_worst {nrmse, dof}, model_note
               (why the model error was skipped, or null)
  model_error_groups  {group: {n, median, mean, max}}: NRMSE over the reference library
  delivery     joint_states, joint_torques (counts), considered (joint_states judged),
               lost, loss_pct (%), lost_stamps_ns (first 20), tail_grace_s, tail_left_out
               (joint_states of the last tail_grace_s, not judged), tail_answered,
               unmatched_torques, latency_ms {p50, p99, max}, latency_p99_ms_target,
               latency_p99_ms_max (null = not gating), rate_hz, max_gap_ms {topic: value},
               lost_runs (runs of consecutive lost joint_states), behind_after_loss_ms (the
               latest first answer after such a run, beyond the median latency: about the
               node's queue length when it fell behind and DDS dropped samples; null if none)
  std_calibration  null without joint_torques_std, else {groups {group: {coverage, ratio,
               rmse_nm, rms_std_nm, n}}, samples, warming_up, unmatched, model_part,
               coverage_range, ratio_range} (offline/calibration.py)
  machine      cpus, load_average_now [1, 5, 15 min], load_average_during_run [1 min
               values from the torque node's /diagnostics]
  thresholds   the thresholds used (config/check.yaml keys)
  warnings, failures  lists of sentences; exit_code  0, 1 (or 2, never written)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..bag import open_bag, recover
from ..errors import BagNoData, ForeignBag
from ..exit_codes import DATA, OK
from ..model_config import model_from_config
from ..movements import get_movement, movement_library
from ..offline.calibration import gate, score_calibration
from ..offline.check import CheckReport, MovementResult, analyse
from ..offline.delivery import old_stamps_note
from ..offline.recording import read_config, read_recording
from ..offline.thresholds import Thresholds
from ..reference import ReferenceTorques, load_reference, read_reference
from .common import guarded

PROG = "check_bag"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    head, _, rest = __doc__.partition("\n\n")
    ap = argparse.ArgumentParser(prog=PROG, description=head, epilog=rest.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", type=Path, help="MCAP file written by bag_recorder (or ros2 bag)")
    ap.add_argument("--json", type=Path, metavar="OUT", help="write the full report as JSON")
    ap.add_argument("--html", type=Path, metavar="OUT",
                    help="write the report as one self-contained HTML file (plots of every "
                         "movement, tables, histograms; opens offline in any browser)")
    ap.add_argument("--thresholds", type=Path, metavar="YAML",
                    help="thresholds (default: the package's config/check.yaml)")
    ap.add_argument("--reference", type=Path, metavar="NPZ",
                    help="reference torques file (default: the shipped one)")
    ap.add_argument("--recover", type=Path, metavar="OUT",
                    help="rewrite a truncated bag as a complete one into OUT, then exit")
    ap.add_argument("--max-latency-p99-ms", type=float, metavar="MS", default=None,
                    help="exit 1 if the one-way latency p99 exceeds MS (default: report only, "
                         "or latency_p99_ms_max from the thresholds file)")
    ap.add_argument("--std-coverage", type=_range, metavar="LO,HI", default=None,
                    help="fail if any DOF group's coverage of ±1.96σ (joint_torques_std vs the "
                         "exact-state truth) is outside [LO, HI], e.g. 0.90,0.98; default: reported only")
    ap.add_argument("--std-ratio", type=_range, metavar="LO,HI", default=None,
                    help="fail if any DOF group's RMS(σ)/RMSE is outside [LO, HI], e.g. 0.8,1.5; "
                         "default: reported only")
    ap.add_argument("--cutoff", type=float, default=None, metavar="HZ",
                    help="without markers: the reference's zero-phase low-pass cutoff (default "
                         "the practice's 6 Hz, or 0.4 x the bag's rate when lower; said)")
    ap.add_argument("--baseline", type=Path, metavar="OLD",
                    help="regression: compare joint_torques with OLD's, stamp by stamp")
    ap.add_argument("--tolerance", type=float, default=1e-6, metavar="NM",
                    help="with --baseline: largest allowed |difference| (N·m, default 1e-6)")
    return ap.parse_args(argv)


def _range(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give LO,HI (two numbers)") from None
    if not lo <= hi:
        raise argparse.ArgumentTypeError(f"{text!r}: LO must not exceed HI")
    return lo, hi


def _known_movement(movement_id: int) -> bool:
    try:
        get_movement(movement_id)
    except (ValueError, KeyError, IndexError):
        return False
    return True


def _queue_depth(config: dict | None) -> int | None:
    """The torque node's input queue (samples), as its config states it (older bags: None)."""
    depth = ((config or {}).get("input") or {}).get("queue_depth")
    return depth if isinstance(depth, int) and depth > 0 else None


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
        "model": report.model.summary(),
        "joint_names": list(names),
        "movements": [{
            "index": r.index, "id": r.id, "name": r.name, "elbow": r.elbow, "t0_ns": r.t0_ns,
            "samples": r.samples, "expected": r.expected, "shortfall": r.shortfall or None,
            "inputs_missing": r.inputs_missing,
            "state_error_rad": r.state_error, "state_dof": r.state_dof,
            "pipeline_nrmse": dict(zip(names, r.pipeline_nrmse, strict=True)),
            "pipeline_worst": dict(zip(("nrmse", "dof"), r.worst(r.pipeline_nrmse, names), strict=True)),
            "pipeline_left_out": r.pipeline_left_out,
            "model_nrmse": None if r.model_nrmse is None else dict(zip(names, r.model_nrmse, strict=True)),
            "model_worst": dict(zip(("nrmse", "dof"), r.worst(r.model_nrmse, names), strict=True)),
            "model_note": r.model_note or None,
        } for r in report.movements],
        "model_error_groups": report.model_groups,
        "delivery": {
            "joint_states": d.joint_states, "joint_torques": d.joint_torques,
            "considered": d.considered, "lost": d.lost, "loss_pct": d.loss_pct,
            "lost_stamps_ns": d.lost_stamps_ns, "tail_grace_s": d.tail_grace_s,
            "tail_left_out": d.tail_left_out, "tail_answered": d.tail_answered,
            "unmatched_torques": d.unmatched_torques, "latency_ms": d.latency_ms,
            "latency_p99_ms_target": th.latency_p99_ms_target,
            "latency_p99_ms_max": th.latency_p99_ms_max,
            "rate_hz": d.rate_hz, "max_gap_ms": d.max_gap_ms,
            "lost_runs": d.lost_runs, "behind_after_loss_ms": d.behind_after_loss_ms,
        },
        "machine": {"cpus": report.load.cpus, "load_average_now": report.load.now,
                    "load_average_during_run": report.load.during_run},
        "thresholds": th.__dict__,
        "warnings": report.warnings,
        "failures": report.failures,
        "exit_code": code,
    })


def _n(x: int) -> str:
    """97400 -> '97 400', as the README writes counts."""
    return f"{x:,}".replace(",", " ")


def _pct(x: float | None, digits: int = 2) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{100 * x:.{digits}f}"


def latency_lines(report: CheckReport, th: Thresholds) -> list[str]:
    """Latency against its target, the load it was measured under, and whether it gates."""
    lat = report.delivery.latency_ms
    if not lat:
        return ["latency: no joint_torques answered a joint_states; nothing to measure"]
    p99 = lat["p99"]
    target = th.latency_p99_ms_target
    lines = [f"latency (recorder receive - stamp): p50 {_num(lat['p50'], '.3f')} ms, p99 "
             f"{_num(p99, '.3f')} ms, max {_num(lat['max'], '.3f')} ms; target p99 < {target:g} ms: "
             + ("met" if p99 <= target else "NOT met")]
    gate = ("gates the exit code (maximum " f"{th.latency_p99_ms_max:g} ms)"
            if th.latency_p99_ms_max is not None else
            "reported only: a slow machine is not wrong data (gate with --max-latency-p99-ms)")
    lines.append(f"  machine: {report.load.describe()}; latency {gate}")
    old = old_stamps_note(report.delivery, th.old_stamps_latency_s)
    if old:
        lines.append(f"  note: {old}")
    elif p99 > target:
        lines.append("  slow, not wrong: on a shared or loaded machine the nodes wait for a CPU, "
                     "and every wait adds to the latency")
    return lines


#: A per-movement model NRMSE above this (a fraction) gets the note on its normalisation.
PER_MOVEMENT_NOTE = 0.10


def print_report(report: CheckReport, bag_info, th: Thresholds | None = None, out=None,
                 extra: list[str] | tuple[str, ...] = ()) -> None:
    """The human report: every number with its unit; notes only where there is one."""
    out = out or sys.stdout
    th = th or Thresholds()
    names = report.joint_names
    p = lambda *a: print(*a, file=out)
    p(f"{bag_info.path}: {bag_info.message_count} messages, {len(report.movements)} movements; "
      f"model {report.model.describe()}")
    for w in report.warnings:
        p(f"warning: {w}")
    p(f"{'id':>3} {'name':<32} {'elbow':<16} {'samples':>8} {'state err':>9}  "
      f"{'pipeline NRMSE':>14} {'(worst DOF)':<20} {'model NRMSE':>11} (worst DOF)")
    p(f"{'':>3} {'':<32} {'':<16} {'':>8} {'(rad)':>9}  {'(%)':>14} {'':<20} {'(%)':>11}")
    notes: list[tuple[str, MovementResult, str]] = []
    for r in report.movements:
        pv, pd = r.worst(r.pipeline_nrmse, names)
        mv, md = r.worst(r.model_nrmse, names)
        flag = "!" if r.shortfall else " "
        p(f"{r.id:>3} {r.name[:32]:<32} {r.elbow[:16]:<16} {r.samples:>7}{flag} "
          f"{_num(r.state_error, '.1e'):>9}  {_pct(pv, 3):>14} {pd:<20} {_pct(mv):>11} {md}")
        notes += [("!", r, note) for note in (r.shortfall, r.model_note and f"model error skipped: "
                                              f"{r.model_note}") if note]
        if r.model_nrmse is not None and not np.isfinite(r.model_nrmse).any():
            notes.append(("-", r, (f"model NRMSE '-': no DOF's reference torque moves by "
                          f"{100 * th.model_rel_floor:g} % of its largest peak-to-peak in this "
                          "movement (model_rel_floor); nothing to compare")))
    for mark, r, note in notes:
        p(f"  {mark} movement {r.id} (index {r.index}): {note}")
    if report.model_groups:
        p("model NRMSE by DOF group, % (RMSE / the DOF's largest reference peak-to-peak; "
          "median / max): " + ", ".join(
              f"{g} {_pct(s['median'])}/{_pct(s['max'])}" for g, s in report.model_groups.items()))
        worst = [r.worst(r.model_nrmse, names)[0] for r in report.movements
                 if r.model_nrmse is not None]
        if any(np.isfinite(w) and w > PER_MOVEMENT_NOTE for w in worst):
            p("  (the table's model column divides by that movement's own reference peak-to-peak, "
              "the paper's metric: a DOF that barely moves there, e.g. an elbow held still, reads "
              "tens of % for an error of a few mN·m; the pass/fail gate is this line, normalised "
              "by the DOF's largest peak-to-peak over all movements: config/check.yaml)")
    d = report.delivery
    p(f"delivery: joint_states {_n(d.joint_states)} "
      f"({_num(d.rate_hz.get('joint_states', math.nan), '.1f')} Hz), joint_torques "
      f"{_n(d.joint_torques)} ({_num(d.rate_hz.get('joint_torques', math.nan), '.1f')} Hz)")
    if d.joint_states:
        p(f"  lost {_n(d.lost)} of {_n(d.considered)} joint_states ({_num(d.loss_pct, '.3f')} %) "
          "= without a joint_torques of the same stamp")
        if d.tail_left_out:
            p(f"  left out: the last {_n(d.tail_left_out)} joint_states, received in the last "
              f"{d.tail_grace_s:g} s of the stream (tail_grace_s): their answers may come after the "
              f"recorder stops ({_n(d.tail_answered)} of them were answered in the bag)")
    for line in latency_lines(report, th):
        p(line)
    for line in extra:  # e.g. the σ calibration lines
        p(line)
    for f in report.failures:
        p(f"FAIL: {f}")
    p("PASS: the data are right" if not report.failures else
      f"FAIL ({len(report.failures)} threshold(s) exceeded)")


def _recover(src: Path, dst: Path) -> int:
    res = recover(src, dst)
    state = "complete" if res.source_complete else f"damaged: {res.problem}"
    counts = ", ".join(f"{t} {n}" for t, n in res.counts.items())
    print(f"{PROG}: recovered {res.messages} messages ({counts}) from {src} ({state}) into {dst}")
    return OK


def _regression(args: argparse.Namespace) -> int:
    from ..offline import regression

    rep = regression.compare(args.bag, args.baseline, args.tolerance)
    code = DATA if rep.failures else OK
    print("\n".join(regression.format_report(rep)))
    if args.json is not None:
        args.json.write_text(json.dumps({**regression.to_dict(rep), "exit_code": code}, indent=1),
                             encoding="utf-8")
    return code


def _markerless(args: argparse.Namespace, rec, choice, th: Thresholds, info,
                config: dict | None) -> int:
    from ..offline import score

    if rec.joint_states is None or len(rec.joint_states) == 0:
        raise ForeignBag(f"{args.bag}: no movement markers and no joint_states: "
                       "nothing to compute a reference from")
    if not info.complete:
        rec.warnings.insert(0, f"bag is truncated ({info.problem}); analysing the "
                            f"{info.message_count} messages of its complete chunks")
    report = score.analyse_markerless(rec, choice, th, cutoff_hz=args.cutoff,
                                      queue_depth=_queue_depth(config))
    code = DATA if report.failures else OK
    print("\n".join(score.format_score(report, info)))
    if args.html is not None:
        from ..offline.html_report import render_segment, write_html
        from ..offline.muscle_html import with_muscles

        write_html(args.html, with_muscles(render_segment(report, rec, info, code), open_bag(args.bag)))
    if args.json is not None:
        args.json.write_text(json.dumps({**score.score_dict(report), "exit_code": code}, indent=1),
                             encoding="utf-8")
    return code


def run(args: argparse.Namespace) -> int:
    if args.html is not None and (args.recover is not None or args.baseline is not None):
        raise ValueError("--html writes a run's check; it does not go with --recover or --baseline")
    if args.recover is not None:
        return _recover(args.bag, args.recover)
    if args.baseline is not None:
        return _regression(args)
    th = Thresholds.load(args.thresholds)
    if args.max_latency_p99_ms is not None:
        if not args.max_latency_p99_ms > 0:
            raise ValueError(f"--max-latency-p99-ms must be > 0, got {args.max_latency_p99_ms}")
        th = replace(th, latency_p99_ms_max=args.max_latency_p99_ms)
    bag = open_bag(args.bag)
    info = bag.info
    if info.message_count == 0:
        raise BagNoData(f"{args.bag}: no messages"
                       + (f" recovered ({info.problem})" if info.problem else ""))
    torques_ch = info.find_topic("joint_torques")
    if torques_ch is None:
        raise ForeignBag(f"{args.bag}: no joint_torques topic (topics: "
                       f"{', '.join(sorted(info.topic_counts())) or 'none'}); not a forearm_dynamics run")
    if info.counts.get(torques_ch.id, 0) == 0:
        why = f"truncated ({info.problem}) before its first complete chunk with joint_torques" \
            if not info.complete else "joint_torques was recorded but holds no message"
        raise BagNoData(f"{args.bag}: {why}")
    # The config first (it names the model, hence the joint order), then one pass for the rest.
    config, config_warnings = read_config(bag)
    try:
        choice = model_from_config(config)
    except (ValueError, TypeError, KeyError) as exc:
        raise ForeignBag(f"{args.bag}: torque_node/config names a model that cannot be "
                       f"built ({exc})") from None
    rec = read_recording(bag, choice.arm.joint_names)
    rec.warnings[:0] = config_warnings
    if not rec.markers:  # any recording (a subject's session): scored as one segment
        return _markerless(args, rec, choice, th, info, config)
    if args.cutoff is not None:
        raise ValueError("--cutoff sets the reference of a bag without movement markers; this "
                         "bag has markers (its reference is the movements' own torques)")
    if not any(_known_movement(m.id) for m in rec.markers):
        ids = sorted({m.id for m in rec.markers})
        raise ForeignBag(f"{args.bag}: no movement marker names a known movement (ids "
                       f"{ids[:5]}{' ...' if len(ids) > 5 else ''}; known 1..{len(movement_library())})")
    if not np.isfinite(rec.joint_torques.effort).all(axis=1).any():
        raise ForeignBag(f"{args.bag}: no joint_torques message carries an effort for every "
                       f"joint of the {choice.arm.kind} model; not this model's torques")
    if not info.complete:
        rec.warnings.insert(0, f"bag is truncated ({info.problem}); analysing the "
                            f"{info.message_count} messages of its complete chunks")
    ref, ref_problem = _reference(args.reference)
    report = analyse(rec, choice, ref, th, ref_problem, queue_depth=_queue_depth(config))
    cal = score_calibration(rec, choice.arm, config)
    report.failures += gate(cal, args.std_coverage, args.std_ratio)
    code = DATA if report.failures else OK
    try:
        print_report(report, info, th, extra=() if cal is None else cal.lines())
        sys.stdout.flush()
    except BrokenPipeError:  # `check_bag BAG | head`: the reader left; keep the exit code
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    if args.json is not None:
        doc = to_json(report, info, th, code)
        doc["std_calibration"] = None if cal is None else _clean(
            {"groups": cal.groups, "samples": cal.samples, "warming_up": cal.warming_up,
             "unmatched": cal.unmatched, "model_part": cal.model_part,
             "coverage_range": args.std_coverage, "ratio_range": args.std_ratio})
        args.json.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    if args.html is not None:
        from ..offline.html_report import render, write_html
        from ..offline.muscle_html import with_muscles

        write_html(args.html, with_muscles(render(report, rec, ref, info, code,
                                                  latency_lines(report, th)), bag))
    return code


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    return guarded(PROG, run, args, f"{args.bag}: cannot analyse")


if __name__ == "__main__":
    sys.exit(main())
