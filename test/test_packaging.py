"""Packaging: the core and the offline tools import without rclpy or any ROS message package.

A fresh interpreter with a sys.meta_path finder that refuses rclpy, rcl_interfaces,
builtin_interfaces and every *_msgs package imports every module outside nodes/ and cli/,
the offline tools' main modules, computes torques with the core, and prints each offline
tool's --help (exit 0). ROS stays a required dependency (setup.py; docs/architecture.md says
why): reading or writing message bytes needs rclpy's serialiser, loaded on first use
(codec/ros.py).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from forearm_dynamics import build_model

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parent.parent
TOOLS = ("bag_torques", "mot_to_bag", "check_bag", "bag_export", "reproduce_paper", "export_urdf")

BLOCK = '''
import importlib.abc, sys
class NoRos(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        top = name.split(".")[0]
        if top in ("rclpy", "rcl_interfaces", "builtin_interfaces", "rosidl_runtime_py") \\
                or top.endswith("_msgs"):
            raise ImportError(f"blocked for this test: {name}")
sys.meta_path.insert(0, NoRos())
'''

SCRIPT = BLOCK + '''
import importlib, json, pkgutil, runpy, contextlib, io
import forearm_dynamics
out = {"failed": {}, "imported": 0, "help": {}}
names = [m.name for m in pkgutil.walk_packages(forearm_dynamics.__path__, "forearm_dynamics.")
         if not m.name.startswith(("forearm_dynamics.nodes", "forearm_dynamics.cli"))]
names += [f"forearm_dynamics.cli.{t}" for t in TOOLS]
# the parameter tables and the torque node's live model are ROS-free too
names += [f"forearm_dynamics.nodes.{m}" for m in ("spec", "catalog", "torque_config", "live_model")]
for name in names:
    try:
        importlib.import_module(name)
        out["imported"] += 1
    except ImportError as exc:
        out["failed"][name] = str(exc)
from forearm_dynamics import build_model
import numpy as np
arm = build_model("segmented", 50)
q = np.linspace(-0.5, 0.5, 20)
out["tau"] = arm.inverse_dynamics(q, np.cos(q), np.sin(q)).tolist()
for tool in TOOLS:
    sys.argv = [tool, "--help"]
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            importlib.import_module(f"forearm_dynamics.cli.{tool}").main()
    except SystemExit as exc:
        out["help"][tool] = [exc.code, buf.getvalue()[:40]]
print(json.dumps(out))
'''


def test_core_and_offline_tools_import_and_run_without_ros() -> None:
    code = f"TOOLS = {TOOLS!r}\n" + SCRIPT
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       cwd=ROOT, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["failed"] == {}
    assert out["imported"] > 60
    arm = build_model("segmented", 50)  # the same torques as with ROS importable
    q = np.linspace(-0.5, 0.5, 20)
    assert out["tau"] == arm.inverse_dynamics(q, np.cos(q), np.sin(q)).tolist()
    assert {t: c for t, (c, _text) in out["help"].items()} == dict.fromkeys(TOOLS, 0)
    assert all(text.startswith("usage:") for _c, text in out["help"].values())


def test_the_blocker_blocks() -> None:
    """The finder really refuses rclpy: the same interpreter cannot import a node."""
    code = BLOCK + "import forearm_dynamics.nodes.torque_node\n"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       cwd=ROOT, check=False)
    assert r.returncode != 0 and "blocked for this test" in r.stderr
