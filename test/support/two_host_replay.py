"""The one two-host replay: trajectory_publisher and bag_recorder in host B against a torque
node already started in host A, then check_bag on B's bag (test_two_hosts*.py)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import hostkit

from forearm_dynamics.processes import BIN


def replay_in_b(h: hostkit.TwoHosts, node, env_b: dict[str, str], tmp: Path, bag: Path,
                movements: str, subscriber_timeout: float, hang_s: float = 180.0) -> dict:
    """Record and replay `movements` in B, stop the recorder and `node`, check B's bag.

    start_delay 8 s: the publisher waits for its joint_states subscribers only; B's recorder
    matched A's joint_torques ~0.3 s later across the link in a loaded run (296 first answers
    unrecorded with 2 s). Returns check_bag's exit code (`code`), output (`out`), JSON report
    (`report`, None without one) and the node's log (`node_log`, tmp / "a_node.log")."""
    rec = h.b.start([str(BIN / "bag_recorder"), "--ros-args", "-p", f"output:={bag}"], env_b,
                    tmp / "b_rec.log")
    pub = h.b.start([str(BIN / "trajectory_publisher"), "--ros-args", "-p", f"movements:={movements}",
                     "-p", "start_delay:=8.0", "-p", "min_subscribers:=2", "-p",
                     f"subscriber_timeout:={subscriber_timeout}"], env_b, tmp / "b_pub.log")
    assert pub.wait(timeout=hang_s) == 0, (tmp / "b_pub.log").read_text()[-2000:]
    for p in (rec, node):
        p.send_signal(2)
        assert p.wait(timeout=30) == 0
    report = tmp / "check.json"
    r = subprocess.run([str(BIN / "check_bag"), str(bag), "--json", str(report)], check=False,
                       capture_output=True, text=True, timeout=300)
    return {"code": r.returncode, "out": r.stdout + r.stderr,
            "report": json.loads(report.read_text()) if report.exists() else None,
            "node_log": (tmp / "a_node.log").read_text()}
