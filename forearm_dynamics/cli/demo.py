"""demo: torque node, recorder and replay of the 65 movements as separate processes, then check.

Starts `torque_node` and `bag_recorder`, waits until both listen on `joint_states`, runs
`trajectory_publisher` (all 65 movements, 50th percentile) to the end, stops the nodes it
started (SIGINT, by PID), runs `check_bag` and draws the recorded torques. DDS stays on
loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) in its own ROS_DOMAIN_ID.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from ..exit_codes import DATA, OK
from ..processes import BIN, Child, ros_env
from .common import die


def wait_for_listeners(env: dict, topic: str, count: int, timeout: float) -> bool:
    """Ask the ROS graph (from a short-lived child) until `count` nodes subscribe to topic."""
    code = (
        "import sys, time, rclpy\n"
        "rclpy.init(); n = rclpy.create_node('demo_probe')\n"
        f"end = time.monotonic() + {timeout}\n"
        f"while time.monotonic() < end and n.count_subscribers('{topic}') < {count}:\n"
        "    rclpy.spin_once(n, timeout_sec=0.1)\n"
        f"ok = n.count_subscribers('{topic}') >= {count}\n"
        f"n.destroy_node(); rclpy.shutdown(); sys.exit({OK} if ok else {DATA})\n"
    )
    return subprocess.run([sys.executable, "-c", code], env=env, timeout=timeout + 30,
                          check=False).returncode == OK


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="demo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("demo_out"))
    ap.add_argument("--movements", default="", help="comma-separated ids (default: all 65)")
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "73") or 73))
    args = ap.parse_args(argv)
    stamp = time.strftime("%Y%m%d_%H%M%S")
    out = args.out / stamp
    try:
        (out / "logs").mkdir(parents=True, exist_ok=False)
    except OSError as exc:
        return die(f"demo: cannot create {out}: {exc.strerror or exc}")
    env = ros_env(args.domain, out / "logs")
    bag = out / "run.mcap"
    ids = [int(x) for x in args.movements.split(",") if x.strip()]
    pub_args = ["-p", "loop:=false", "-p", "min_subscribers:=2"]
    if ids:
        pub_args += ["-p", f"movements:={ids}"]
    t0 = time.monotonic()
    print(f"demo: ROS_DOMAIN_ID={args.domain}, loopback only; output in {out}")
    children = [Child.script("torque_node", [], env, out / "logs"),
                Child.script("bag_recorder", ["-p", f"output:={bag}"], env, out / "logs")]
    try:
        if not wait_for_listeners(env, "joint_states", 2, timeout=30.0):
            return die("demo: torque_node and bag_recorder did not come up; see " + str(out / "logs"))
        n = len(ids) or 65
        print(f"demo: replaying {n} movements at 1 kHz (~{n * 1.5:.0f} s)...", flush=True)
        pub = Child.script("trajectory_publisher", pub_args, env, out / "logs")
        code = pub.wait(timeout=n * 1.5 * 3 + 60)
        pub.stop()
        if code != OK:
            return die(f"demo: trajectory_publisher exited {code}; see {pub.log}")
        time.sleep(0.5)  # let the last answers reach the recorder
    finally:
        codes = {c.name: c.stop() for c in reversed(children)}
    if any(codes.values()):
        return die(f"demo: a node exited badly {codes}; logs in {out / 'logs'}")
    report = out / "check.json"
    check = subprocess.run([str(BIN / "check_bag"), str(bag), "--json", str(report)], env=env,
                           check=False)
    plot = out / "torques.png"
    try:
        from .demo_plot import draw

        draw(bag, plot)
    except Exception as exc:  # noqa: BLE001 - a missing plot must not hide the check result
        print(f"demo: no plot ({exc})", file=sys.stderr)
    summary = json.loads(report.read_text()) if report.is_file() else {}
    print(f"\ndemo finished in {time.monotonic() - t0:.0f} s: check_bag exit {check.returncode} "
          f"({'PASS' if check.returncode == OK else 'FAIL'})")
    print(f"  bag:    {bag}\n  report: {report}\n  plot:   {plot}\n  logs:   {out / 'logs'}")
    if summary.get("failures"):
        print("  failures: " + "; ".join(summary["failures"][:5]))
    return check.returncode


if __name__ == "__main__":
    sys.exit(main())
