"""`make bench`: every performance figure of the package, measured on this machine in one run.

    python -m benchmarks [--out benchmarks/results.json] [--quick]
                         [--sections compute,torque,choices,recorder,offline] [--choices a,b]

Run from the repository root. Prints a table and updates a JSON file: the sections of
this run replace theirs, every other top-level key (e.g. another benchmark's section) is
kept (benchmarks/stats.py). Child processes run on loopback DDS only
(ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) in ROS_DOMAIN_ID --domain (default: the
environment's if set and not 0, else 75); they are stopped by PID. Full run ~7-9 min on
2 cores; --quick (1 movement, 1 s recorder steps, no reproduce_paper, no choices) ~25 s.

results.json keys (times in the unit their name says; `p50/p99/p99_9/max/mean/n` are
percentiles over every sample of that run):

- `schema` (1), `mode` ("full" | "quick"), `command`, `started` (ISO time), `wall_time_s`,
  `domain_id`, `machine` {machine, cores, cpu, python, platform, loadavg_start,
  loadavg_end}, `versions` {rclpy, fastrtps, pin, numpy, forearm_dynamics}.
- `compute.per_sample`: `inverse_dynamics` and `bare_rnea` {n, p50, p99, p99_9, max, mean}
  in µs (segmented model; the two calls alternate sample by sample), `ratio_p50`, `ratio_p99`.
- `torque_path` (torque_path.py): `movements`, `start_delay_s`, `recorder_movements`,
  `variants.<name>` for `null_echo_node` and `torque_node` (the 65-movement replay at
  1 kHz each) and `torque_node+bag_recorder` (`recorder_movements` movements with the
  recorder on its default topics), each with:
  - what ran: `node`, `movements`, `node_args`, `env`, `with_recorder`, `node_cpus`;
  - counts: `expected`, `sent` (the publisher's count), `skipped_by_publisher`,
    `received`, `unique`, `duplicates`, `lost`, `loss_fraction`;
  - rates: `rate_hz` (received / receive span), `input_rate_hz` (from the stamps),
    `replay_s`;
  - latency (receive time of joint_torques at the receiver - header stamp of the
    joint_states it answers): `latency_ms` {n, p50, p99, p99_9, max, mean},
    `first_latency_ms`, `late_over_1ms_fraction`, `receive_gap_ms_max`,
    `stalls_over_100ms`, `latency_worst_at_s` (after the publisher process started);
  - `callback_us` {periods, p50, p99, p99_worst_period, max, publish_p50, publish_p99,
    own_p50, own_p99}: the node's /diagnostics, median over its 1 s periods; publish_* =
    the time inside publish() (the DDS write), own_* = callback - publish per sample;
  - processes: `node_process`, `publisher_process`, `receiver_process` (and
    `bag_recorder_process`) {cpu_percent (of one core, over the replay), peak_rss_mb
    (VmHWM), rss_start_mb, rss_end_mb}; `foreign_cpu_percent` (CPU used by processes
    not ours during the replay: other load on the machine); `exit_codes`.
  `ratio_to_null` {latency_p50, latency_p99, callback_p50, callback_p99, cpu}:
  torque_node / null_echo_node.
- `choices`: `movements`, `start_delay_s` (1 s: streaming spans the window where a rare
  ~0.3 s delivery stall was seen), `variants.<name>` {what, rate_hz, lost, latency_ms,
  first_latency_ms, stalls_over_100ms, receive_gap_ms_max, latency_worst_at_s,
  callback_us, cpu_percent, foreign_cpu_percent} (or {what, error}): short torque_node
  replays comparing executor, QoS, transport, publication mode and CPU pinning against
  the defaults (`choices()` lists them).
- `recorder` (recorder.py): `topics`, `sustained_msgs_per_s`, `nominal_target_msgs_per_s`,
  `nominal_dropped`, `max_rate_kept_up_msgs_per_s`, `max_rate_is_lower_bound`,
  `generator_limited`, `recorder_peak_rss_mb`, `bag_bytes`, `steps[]` {target_msgs_per_s,
  offered_msgs_per_s, generator_fraction, sent, written, dropped, written_msgs_per_s,
  acked, recorder_cpu_percent}, `exit_code`.
- `offline`: `reproduce_paper` {wall_time_s, exit_code, outputs} (or {skipped}),
  `batch.<model>` {samples, seconds_best, seconds_all, samples_per_s}.
- `goals.<name>` {target, value, met}: the issue's targets, evaluated on the numbers in
  the file (a report, not a test).
- `sections.<key>` {command, started}: the run that wrote each section.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from forearm_dynamics.exit_codes import OK
from forearm_dynamics.movements import movement_library
from forearm_dynamics.paths import config_file
from forearm_dynamics.processes import ros_env

from . import compute, offline, recorder
from .stats import claim_domain_arg, loadavg, machine_info, merge_results, write_json
from .torque_path import Variant, run_variant

SECTIONS = ("compute", "torque", "choices", "recorder", "offline")
RECORDER_MOVEMENTS = 20  # the torque_node + bag_recorder variant (30 s)
CHOICE_MOVEMENTS = 6  # 9 s per choice variant
CHOICE_START_DELAY = 1.0  # s: streaming reaches the ~3 s-after-start window (see choices)


#: trajectory_publisher as a motion-capture-like sensor: positions only, white noise (issue 29
#: item 5 measures the estimator's cost in the node on such input, not only on exact input)
POSITIONS_ONLY = ["-p", "publish_velocity:=false", "-p", "noise_deg:=0.3"]


def choices() -> list[tuple[Variant, str]]:
    """Alternatives measured against the defaults (torque_node, events, reliable 1000, default transport)."""
    shm = str(config_file("fastdds_shm.xml"))
    return [
        (Variant("default"), "EventsExecutor, reliable depth 1000, Fast DDS default transports"),
        (Variant("single_executor", node_args=["-p", "executor:=single"]),
         "SingleThreadedExecutor in torque_node"),
        (Variant("backward_estimator", node_args=["-p", "estimator:=backward"]),
         "the backward-difference estimator instead of the default kalman (its cost in the node)"),
        (Variant("best_effort", node_args=["-p", "qos_reliable:=false"], best_effort=True),
         "best-effort joint_states and joint_torques"),
        (Variant("depth_10", node_args=["-p", "qos_depth:=10"]),
         "history depth 10 in torque_node (publisher and receiver keep 1000)"),
        (Variant("shm_profile", env={"FASTRTPS_DEFAULT_PROFILES_FILE": shm}),
         "every process: config/fastdds_shm.xml (shared memory only)"),
        (Variant("udp_only", env={"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}),
         "every process: FASTDDS_BUILTIN_TRANSPORTS=UDPv4"),
        (Variant("async_publish", env={"RMW_FASTRTPS_PUBLICATION_MODE": "ASYNCHRONOUS"}),
         "every process: RMW_FASTRTPS_PUBLICATION_MODE=ASYNCHRONOUS"),
        (Variant("pinned", pin=True),
         "torque_node alone on the last CPU (affinity), publisher and receiver on the others"),
        (Variant("positions_kalman", pub_args=POSITIONS_ONLY),
         "positions only, 0.3 deg noise (a motion-capture-like input), the default kalman"),
        (Variant("positions_backward", node_args=["-p", "estimator:=backward"], pub_args=POSITIONS_ONLY),
         "positions only, 0.3 deg noise, the backward-difference estimator (the kalman's cost there)"),
    ]


def _versions() -> dict:
    from importlib import metadata

    out = {}
    for key, dist in (("rclpy", "ros-rclpy"), ("fastrtps", "ros-fastrtps"), ("pin", "pin"),
                      ("numpy", "numpy"), ("forearm_dynamics", "forearm_dynamics")):
        try:
            out[key] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[key] = None
    return out


def _ratio(a, b):
    return a / b if a is not None and b else None


def torque_section(domain: int, work: Path, quick: bool) -> dict:
    n_all = len(movement_library())
    movements = [1] if quick else list(range(1, n_all + 1))
    delay = 0.3 if quick else 5.0
    variants = [Variant("null_echo_node", node="null_echo_node"), Variant("torque_node")]
    rec_movements = [] if quick else list(range(1, RECORDER_MOVEMENTS + 1))
    out: dict = {"movements": len(movements), "start_delay_s": delay,
                 "recorder_movements": len(rec_movements), "variants": {}}
    for v in variants:
        _say(f"torque path: {v.name}, {len(movements)} movement(s) at 1 kHz ...")
        out["variants"][v.name] = run_variant(v, movements, domain, work, start_delay=delay)
    if rec_movements:
        v = Variant("torque_node+bag_recorder", recorder=True)
        _say(f"torque path: {v.name}, {len(rec_movements)} movements ...")
        out["variants"][v.name] = run_variant(v, rec_movements, domain, work, start_delay=delay)
    t, n = out["variants"]["torque_node"], out["variants"]["null_echo_node"]

    def get(r, *keys):
        for k in keys:
            r = (r or {}).get(k)
        return r

    out["ratio_to_null"] = {
        "latency_p50": _ratio(get(t, "latency_ms", "p50"), get(n, "latency_ms", "p50")),
        "latency_p99": _ratio(get(t, "latency_ms", "p99"), get(n, "latency_ms", "p99")),
        "callback_p50": _ratio(get(t, "callback_us", "p50"), get(n, "callback_us", "p50")),
        "callback_p99": _ratio(get(t, "callback_us", "p99"), get(n, "callback_us", "p99")),
        "cpu": _ratio(get(t, "node_process", "cpu_percent"), get(n, "node_process", "cpu_percent")),
    }
    return out


def choices_section(domain: int, work: Path, only: set[str] | None = None) -> dict:
    movements = list(range(1, CHOICE_MOVEMENTS + 1))
    out: dict = {"movements": len(movements), "start_delay_s": CHOICE_START_DELAY, "variants": {}}
    for v, what in choices():
        if only and v.name not in only:
            continue
        _say(f"choices: {v.name} ({what}) ...")
        v.name = f"choice_{v.name}"
        try:
            r = run_variant(v, movements, domain, work, start_delay=CHOICE_START_DELAY)
        except RuntimeError as exc:
            out["variants"][v.name.removeprefix("choice_")] = {"what": what, "error": str(exc)[:500]}
            continue
        out["variants"][v.name.removeprefix("choice_")] = {
            "what": what, "rate_hz": r.get("rate_hz"), "lost": r.get("lost"),
            "latency_ms": r.get("latency_ms"), "stalls_over_100ms": r.get("stalls_over_100ms"),
            "receive_gap_ms_max": r.get("receive_gap_ms_max"),
            "latency_worst_at_s": r.get("latency_worst_at_s"), "callback_us": r.get("callback_us"),
            "first_latency_ms": r.get("first_latency_ms"),
            "foreign_cpu_percent": r.get("foreign_cpu_percent"),
            "cpu_percent": (r.get("node_process") or {}).get("cpu_percent"),
        }
    return out


def goals(res: dict) -> dict:
    def at(*keys):
        r = res
        for k in keys:
            if not isinstance(r, dict):
                return None
            r = r.get(k)
        return r

    t = ("torque_path", "variants", "torque_node")
    g = {
        "rate_hz_min_1000": (">= 1000 (input 1 kHz)", at(*t, "rate_hz"),
                             lambda x: x >= 0.999 * (at(*t, "input_rate_hz") or 1000.0)),
        "lost_0": ("0", at(*t, "lost"), lambda x: x == 0),
        "latency_p50_ms_lt_0.5": ("< 0.5 ms", at(*t, "latency_ms", "p50"), lambda x: x < 0.5),
        "latency_p99_ms_lt_1": ("< 1 ms", at(*t, "latency_ms", "p99"), lambda x: x < 1.0),
        "latency_p50_ratio_to_null_le_1.15": ("<= 1.15", at("torque_path", "ratio_to_null", "latency_p50"),
                                              lambda x: x <= 1.15),
        "callback_p99_us_lt_150": ("< 150 us", at(*t, "callback_us", "p99"), lambda x: x < 150),
        "per_sample_id_ratio_le_1.3": ("<= 1.3", at("compute", "per_sample", "ratio_p50"),
                                       lambda x: x <= 1.3),
        "cpu_percent_lt_50": ("< 50 %", at(*t, "node_process", "cpu_percent"), lambda x: x < 50),
    }
    return {k: {"target": tgt, "value": v, "met": (bool(ok(v)) if v is not None else None)}
            for k, (tgt, v, ok) in g.items()}


def _say(text: str) -> None:
    print(f"[bench {time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def _f(x, fmt="{:.3g}"):
    return "-" if x is None else fmt.format(x)


def table(res: dict) -> str:
    lines = []
    c = res.get("compute", {}).get("per_sample")
    if c:
        lines += ["## compute floor (µs, segmented model, per sample)",
                  "| call | p50 | p99 | ratio p50 / p99 |", "|---|---|---|---|",
                  f"| bare pin.rnea | {c['bare_rnea']['p50']:.2f} | {c['bare_rnea']['p99']:.2f} | |",
                  (f"| inverse_dynamics | {c['inverse_dynamics']['p50']:.2f} | "
                  f"{c['inverse_dynamics']['p99']:.2f} | {c['ratio_p50']:.3f} / {c['ratio_p99']:.3f} |"), ""]
    tp = res.get("torque_path")
    if tp:
        lines += [(f"## torque path ({tp['movements']} movements at 1 kHz; recorder variant "
                  f"{tp['recorder_movements']})"),
                  ("| variant | rate Hz (input) | lost | latency p50 / p99 / p99.9 / max ms "
                   "| callback p50 / p99 µs (in publish; own) | CPU % | peak RSS MB | RSS start→end MB "
                   "| other load % |"), "|---|---|---|---|---|---|---|---|---|"]
        for name, r in tp["variants"].items():
            lat, cb, pr = r.get("latency_ms", {}), r.get("callback_us", {}), r.get("node_process", {})
            lines.append(
                f"| {name} | {_f(r.get('rate_hz'), '{:.1f}')} ({_f(r.get('input_rate_hz'), '{:.1f}')}) "
                f"| {r.get('lost')} | "
                f"{_f(lat.get('p50'), '{:.3f}')} / {_f(lat.get('p99'), '{:.3f}')} / "
                f"{_f(lat.get('p99_9'), '{:.2f}')} / {_f(lat.get('max'), '{:.2f}')} | "
                f"{_f(cb.get('p50'), '{:.0f}')} / {_f(cb.get('p99'), '{:.0f}')} "
                f"({_f(cb.get('publish_p50'), '{:.0f}')} / {_f(cb.get('publish_p99'), '{:.0f}')}; "
                f"own {_f(cb.get('own_p50'), '{:.0f}')} / {_f(cb.get('own_p99'), '{:.0f}')}) | "
                f"{_f(pr.get('cpu_percent'), '{:.1f}')} | {_f(pr.get('peak_rss_mb'), '{:.1f}')} | "
                f"{_f(pr.get('rss_start_mb'), '{:.1f}')}→{_f(pr.get('rss_end_mb'), '{:.1f}')} | "
                f"{_f(r.get('foreign_cpu_percent'), '{:.0f}')} |")
        rn = tp.get("ratio_to_null", {})
        lines += ["", "torque_node / null_echo_node: " + ", ".join(
            f"{k} {_f(v, '{:.3f}')}" for k, v in rn.items()), ""]
    ch = res.get("choices")
    if ch and ch.get("variants"):
        lines += [(f"## choices (torque_node, {ch['movements']} movements, start delay "
                  f"{ch['start_delay_s']} s)"),
                  ("| variant | lost | latency p50 / p99 / max ms | first sample ms | stalls > 100 ms "
                   "| callback p50 / p99 µs | CPU % | other load % |"), "|---|---|---|---|---|---|---|---|"]
        for name, r in ch["variants"].items():
            if "error" in r:
                lines.append(f"| {name} | error: {r['error'][:60]} | | | | | | |")
                continue
            lat, cb = r.get("latency_ms") or {}, r.get("callback_us") or {}
            lines.append(f"| {name} | {r.get('lost')} | {_f(lat.get('p50'), '{:.3f}')} / "
                         f"{_f(lat.get('p99'), '{:.3f}')} / {_f(lat.get('max'), '{:.1f}')} | "
                         f"{_f(r.get('first_latency_ms'), '{:.1f}')} | "
                         f"{r.get('stalls_over_100ms')} | {_f(cb.get('p50'), '{:.0f}')} / "
                         f"{_f(cb.get('p99'), '{:.0f}')} | {_f(r.get('cpu_percent'), '{:.1f}')} | "
                         f"{_f(r.get('foreign_cpu_percent'), '{:.0f}')} |")
        lines.append("")
    rec = res.get("recorder")
    if rec:
        lines += [f"## recorder ({rec['topics']} JointState topics)",
                  f"sustained {_f(rec['sustained_msgs_per_s'], '{:.0f}')} msgs/s written at "
                  f"{rec['nominal_target_msgs_per_s']:.0f} offered, {rec['nominal_dropped']} dropped; "
                  f"max kept up {_f(rec['max_rate_kept_up_msgs_per_s'], '{:.0f}')} msgs/s"
                  + (" (lower bound: every step kept up)" if rec["max_rate_is_lower_bound"] else "")
                  + (" (generator-limited)" if rec["generator_limited"] else ""),
                  "| target msgs/s | offered | written msgs/s | dropped | recorder CPU % |",
                  "|---|---|---|---|---|"]
        for s in rec["steps"]:
            lines.append(f"| {s['target_msgs_per_s']:.0f} | {_f(s['offered_msgs_per_s'], '{:.0f}')} | "
                         f"{_f(s['written_msgs_per_s'], '{:.0f}')} | {s['dropped']} | "
                         f"{_f(s['recorder_cpu_percent'], '{:.1f}')} |")
        lines.append("")
    off = res.get("offline")
    if off:
        rp = off.get("reproduce_paper", {})
        lines += ["## offline",
                  f"reproduce_paper: {_f(rp.get('wall_time_s'), '{:.1f}')} s"
                  + (f" ({rp['skipped']})" if rp.get("skipped") else ""),
                  "batch inverse dynamics: " + ", ".join(
                      f"{k} {b['samples_per_s'] / 1e3:.0f} k samples/s ({b['samples']} in "
                      f"{b['seconds_best']:.2f} s)" for k, b in off.get("batch", {}).items()), ""]
    gl = res.get("goals")
    if gl:
        lines += ["## goals (this run)", "| goal | target | value | met |", "|---|---|---|---|"]
        for k, g in gl.items():
            v = g["value"]
            lines.append(f"| {k} | {g['target']} | {_f(v, '{:.4g}')} | "
                         f"{'-' if g['met'] is None else ('yes' if g['met'] else 'NO')} |")
    return "\n".join(lines)



def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results.json"))
    ap.add_argument("--quick", action="store_true", help="tiny mode (tests): ~25 s")
    ap.add_argument("--sections", default=",".join(SECTIONS))
    env_domain = int(os.environ.get("ROS_DOMAIN_ID") or 0)
    ap.add_argument("--domain", type=int, default=env_domain or 75)
    ap.add_argument("--choices", default="",
                    help="comma-separated choice variants to run (default: all; names in choices())")
    ap.add_argument("--keep", action="store_true", help="keep the logs and bags (path printed)")
    args = ap.parse_args(argv)
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        ap.error(f"unknown sections {sorted(unknown)}; choose from {SECTIONS}")
    lease = claim_domain_arg(ap, args.domain, "benchmarks")  # held until this process exits
    args.domain = lease.domain
    t_start = time.perf_counter()
    res: dict = {
        "schema": 1, "mode": "quick" if args.quick else "full",
        "command": " ".join([Path(sys.executable).name, "-m", "benchmarks",
                             *(argv if argv is not None else sys.argv[1:])]),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "domain_id": args.domain,
        "machine": {**machine_info(), "loadavg_start": loadavg()}, "versions": _versions(),
    }
    work = Path(tempfile.mkdtemp(prefix="forearm_bench_"))
    try:
        if "compute" in sections:
            _say("compute floor ...")
            res["compute"] = {"per_sample": compute.per_sample(n=2000 if args.quick else 50000)}
        if "torque" in sections:
            res["torque_path"] = torque_section(args.domain, work, args.quick)
        if "choices" in sections:
            res["choices"] = ({"skipped": "quick mode", "variants": {}} if args.quick
                              else choices_section(args.domain, work,
                                                   set(filter(None, args.choices.split(",")))))
        if "recorder" in sections:
            _say("recorder ...")
            steps = ((1000, 1), (2000, 0.5)) if args.quick else \
                ((1000, 20), (2000, 5), (4000, 5), (8000, 5), (16000, 5))
            res["recorder"] = recorder.run(args.domain, work, steps=steps,
                                           pause=0.3 if args.quick else 1.0)
        if "offline" in sections:
            off: dict = {}
            if args.quick:
                off["reproduce_paper"] = {"skipped": "quick mode", "wall_time_s": None}
            else:
                _say("offline: reproduce_paper ...")
                off["reproduce_paper"] = offline.reproduce_paper(work, ros_env(args.domain, work))
            _say("offline: batch inverse dynamics ...")
            off["batch"] = {k: compute.batch(k, repeats=1 if args.quick else 3)
                            for k in ("anatomical", "solid", "segmented")}
            res["offline"] = off
    finally:
        if args.keep:
            _say(f"logs kept in {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)
    res["machine"]["loadavg_end"] = loadavg()
    res["wall_time_s"] = time.perf_counter() - t_start
    written = [k for k in ("compute", "torque_path", "choices", "recorder", "offline") if k in res]
    merged = merge_results(args.out, res, {"command": res["command"], "started": res["started"]},
                           [*written, "goals"])
    merged["goals"] = goals(merged)  # on every section in the file, this run's or kept
    write_json(args.out, merged)
    print(table(res))
    print(f"\n{args.out} written ({', '.join(written)}; other sections kept); "
          f"{res['wall_time_s']:.0f} s")
    return OK

if __name__ == "__main__":
    sys.exit(main())
