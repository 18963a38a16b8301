"""Where muscle_node's joint_torques callback spends its time, in process (issue 31).

    python -m benchmarks.muscle_callback [--movements-step 13] [--before DIR] [--rate 1000] > out.json

A real MuscleNode (rclpy; its publishers have no reader) and the torque node's CDR bytes for
the library's movements (every `--movements-step`-th). Per sample, the callback's steps are
run one by one with the node's own objects, in the callback's order, each timed (p50 µs):
shape check, copy + take + stamp, finiteness, the output templates, geometry + QP (set-up, solve,
result: StaticOptimizer.solve_sample_into, one call in the node), writing
both outputs, the two publish() calls, the bookkeeping after the clock. The steps are the
calls `_on_torques` makes (forearm_dynamics/nodes/muscle_node.py); a change there must be
mirrored here.

--before DIR: DIR holds another version's `forearm_dynamics` (e.g. `git archive <commit> |
tar -x -C DIR`), imported as a second package; its MuscleNode and this one are fed the same
bytes alternately, sample by sample (same CPU conditions), and the paired difference of their
whole callbacks is reported: the only fair A/B on a machine whose speed drifts between runs.

--rate HZ (default 1000; 0 = off): the steps and the A/B are run again with the samples paced
at HZ (`sections_paced_us_p50`, `interleaved_paced`), as the node receives them: between two
samples the process sleeps and the caches cool, which the back-to-back figures do not see.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import sys
import time

import numpy as np

from .stats import claim_domain_arg, loadavg, percentiles

_P = time.perf_counter_ns


def torque_payloads(movements):
    """The torque node's joint_torques messages (CDR bytes, the same codec) for `movements`
    (library Movements) at 1 kHz: exact q, q̇ and their inverse dynamics, stamped
    movement id (s) + sample (ms). Shared with benchmarks/muscle_node.py's callback section."""
    from forearm_dynamics.codec.jointstate_cdr import OutputTemplate
    from forearm_dynamics.description import JOINT_NAMES
    from forearm_dynamics.dynamics import build_model

    arm = build_model("segmented", 50)
    tpl = OutputTemplate(JOINT_NAMES, "")
    for mv in movements:
        q, qd, qdd = mv.evaluate(mv.sample_times(1000.0))
        tau = arm.inverse_dynamics_batch(q, qd, qdd)
        for k in range(len(q)):
            np.copyto(tpl.q, q[k])
            np.copyto(tpl.qd, qd[k])
            np.copyto(tpl.effort, tau[k])
            tpl.pack_stamp(1000 * mv.id + k // 1000, k % 1000 * 1_000_000)
            yield tpl.payload()


def _samples(step: int):
    from forearm_dynamics.movements import movement_library

    return torque_payloads(movement_library()[::step])


class Pacer:
    """Sample k starts no earlier than k / rate after the first (rate 0: back to back). A node
    at 1 kHz sleeps between samples and other processes run: its caches and the CPU's state are
    colder than in a back-to-back loop (the whole callback cost 1.2-2.2x its back-to-back
    figure in this benchmark's runs on 2026-12-03, every step slower, at loads 2-4.7), so the
    figure for a 1 kHz callback is the paced one."""

    def __init__(self, rate: float):
        self.period = int(1e9 / rate) if rate > 0 else 0
        self.next = None

    def wait(self) -> None:
        if not self.period:
            return
        now = _P()
        self.next = now if self.next is None else self.next + self.period
        if self.next > now:
            time.sleep((self.next - now) / 1e9)


def sections(node, datas, rate: float = 0.0) -> dict:
    """The callback's steps, timed one by one (see the module docstring)."""
    t: dict[str, list[int]] = {}
    pacer = Pacer(rate)

    def add(key, dt):
        t.setdefault(key, []).append(dt)

    for data in datas:
        pacer.wait()
        t0 = _P()
        plan = node._plan
        if plan.layout is None or not plan.layout.matches(data):
            plan = node._plan = node._plans.find(data)
        t1 = _P()
        plan.buf[:] = data
        node._reader.read(plan)
        sec, nsec = node._stamp(data, 4)
        t2 = _P()
        ok = math.isfinite(node._state_flat.dot(node._ones))
        t3 = _P()
        b = node.bundle
        out, res = node._outputs.get(plan.layout.frame_id)
        t4 = _P()
        _flag, _infeasible, solve_s = b.optimizer.solve_sample_into(
            node.q, node.qd, node.tau, b.geometry, out.q, out.effort, res.effort)
        t5 = _P()
        np.copyto(out.qd, b.geometry[2])
        out.pack_stamp(sec, nsec)
        payload = out.payload()
        reserves = res.stamped(sec, nsec)
        t6 = _P()
        node.pub.publish(payload)
        node.reserves_pub.publish(reserves)
        t7 = _P()
        r = res.effort.tolist()
        big = max(max(r), -min(r))
        node._solve_ns[node._n_solve % len(node._solve_ns)] = round(solve_s * 1e9)
        node._n_solve += 1
        node.stats.record(t7 - t0, 0, t7 - t6)
        t8 = _P()
        if not ok or big < 0:
            raise RuntimeError("non-finite torques in the library's movements")
        for key, a, z in (("shape_check", t0, t1), ("copy_take_stamp", t1, t2),
                          ("finiteness", t2, t3), ("output_templates", t3, t4),
                          ("geometry_qp", t4, t5), ("write_outputs", t5, t6),
                          ("publish_both_no_reader", t6, t7), ("bookkeeping", t7, t8),
                          ("total", t0, t8)):
            add(key, z - a)
        add("qp_solve_time", solve_s * 1e9)
    return {k: round(float(np.percentile(v, 50)) / 1e3, 2) for k, v in t.items()}


def _interleaved(nodes: dict, step: int, rate: float) -> dict:
    """The two nodes fed the same bytes alternately (which goes first alternates too), each
    whole callback timed; the paired difference before - this."""
    calls: dict[str, list[int]] = {k: [] for k in nodes}
    pacer = Pacer(rate)
    for k, data in enumerate(_samples(step)):
        for name in (("this", "before") if k % 2 else ("before", "this")):
            pacer.wait()
            t0 = _P()
            nodes[name]._on_torques(data)
            calls[name].append(_P() - t0)
    d = np.sort(np.array(calls["before"]) - np.array(calls["this"]))
    cut = len(d) // 10
    return {**{f"{k}_callback_us": percentiles(v, 1e-3) for k, v in calls.items()},
            "before_minus_this_us_p50": float(np.median(d)) / 1e3,
            "before_minus_this_us_mean_middle_80pc": float(d[cut:len(d) - cut].mean()) / 1e3}


def _load_other(path: str):
    name = "forearm_dynamics_other"
    spec = importlib.util.spec_from_file_location(
        name, os.path.join(path, "forearm_dynamics", "__init__.py"),
        submodule_search_locations=[os.path.join(path, "forearm_dynamics")])
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return importlib.import_module(f"{name}.nodes.muscle_node")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks.muscle_callback", description=__doc__.split("\n\n")[0])
    ap.add_argument("--movements-step", type=int, default=13)
    ap.add_argument("--before", help="directory holding another version's forearm_dynamics")
    ap.add_argument("--rate", type=float, default=1000.0,
                    help="also run paced at this rate (Hz; 0: back to back only)")
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID") or 0) or 77)
    args = ap.parse_args(argv)
    lease = claim_domain_arg(ap, args.domain, "benchmarks.muscle_callback")
    os.environ.update(ROS_DOMAIN_ID=str(lease.domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    import rclpy

    from forearm_dynamics.nodes.muscle_node import MuscleNode

    other = _load_other(args.before) if args.before else None
    rclpy.init(args=["--ros-args", "-p", "nice:=0", "-p", "diagnostics_period:=0.0",
                     "-p", "config_topic:=''"])
    out = {"command": "python -m benchmarks.muscle_callback " + " ".join(argv or sys.argv[1:]),
           "loadavg_start": loadavg()}
    try:
        node = MuscleNode("muscle_sections")
        out["sections_us_p50"] = sections(node, _samples(args.movements_step))
        if args.rate > 0:
            out["rate_hz"] = args.rate
            out["sections_paced_us_p50"] = sections(node, _samples(args.movements_step), args.rate)
        if other is not None:
            nodes = {"this": MuscleNode("muscle_this"), "before": other.MuscleNode("muscle_before")}
            out["interleaved"] = _interleaved(nodes, args.movements_step, 0.0)
            if args.rate > 0:
                out["interleaved_paced"] = _interleaved(nodes, args.movements_step, args.rate)
    finally:
        rclpy.try_shutdown()
    out["loadavg_end"] = loadavg()
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
