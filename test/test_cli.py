"""export_urdf as a user runs it: a real process, a real file; `make demo`'s domain."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from forearm_dynamics import build_model

pytestmark = pytest.mark.cli

ROOT = Path(__file__).resolve().parents[1]


def run(*args):
    return subprocess.run([sys.executable, "-m", "forearm_dynamics.cli.export_urdf", *args],
                          capture_output=True, text=True, timeout=60, check=False)


def test_export_urdf_writes_a_loadable_model(tmp_path):
    out = tmp_path / "arm.urdf"
    r = run("--model", "segmented", "--body-size", "95", "-o", str(out))
    assert r.returncode == 0, r.stderr
    model = pin.buildModelFromUrdf(str(out))
    assert model.nv == 20
    ref = build_model("segmented", 95)
    moving = sum(model.inertias[i].mass for i in range(1, model.njoints))
    assert abs(moving - sum(link.mass for link in ref.tree.links)) < 1e-12
    names = [model.names[i] for i in range(1, model.njoints)]
    assert sorted(names) == sorted(ref.joint_names)
    lim = model.upperPositionLimit[model.joints[model.getJointId("elbow_flexion")].idx_q]
    assert lim == np.deg2rad(130)
    # visible: one visual and one collision shape per body with mass (humerus included)
    _, collision, visual = pin.buildModelsFromUrdf(
        str(out), geometry_types=[pin.GeometryType.COLLISION, pin.GeometryType.VISUAL])
    bodies = sum(1 for link in (ref.tree.root, *ref.tree.links) if link.mass > 0)
    assert visual.ngeoms == collision.ngeoms == bodies == 19  # humerus, 2 forearm pieces, palm, 15 digits


def test_export_urdf_refuses_bad_input(tmp_path):
    r = run("--model", "segmented", "--body-size", "42")
    assert r.returncode == 2
    assert "body_size 42" in r.stderr and "Traceback" not in r.stderr
    r = run("--model", "segmented", "-o", str(tmp_path / "missing" / "arm.urdf"))
    assert r.returncode == 2
    assert "cannot write" in r.stderr and "Traceback" not in r.stderr


def test_export_urdf_left_female_with_payload(tmp_path):
    out = tmp_path / "left.urdf"
    r = run("--model", "anatomical", "--side", "left", "--body-size", "female_50",
            "--payload-mass", "0.7", "--payload-com=-0.01,-0.06,-0.045",
            "--payload-inertia", "1e-3,8e-4,9e-4,0,0,1e-4", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert "left arm" in r.stderr and "female_50" in r.stderr
    ref = build_model("anatomical", "female_50", side="left", payload_mass=0.7,
                      payload_com=(-0.01, -0.06, -0.045),
                      payload_inertia=(1e-3, 8e-4, 9e-4, 0, 0, 1e-4))
    assert out.read_text(encoding="utf-8") == ref.to_urdf()
    model = pin.buildModelFromUrdf(str(out))
    total = sum(model.inertias[i].mass for i in range(1, model.njoints))
    assert abs(total - 0.7 - sum(link.mass for link in ref.tree.links)) < 1e-12


def test_export_urdf_refuses_bad_personalisation():
    for args, words in ((("--payload-mass", "-2"), "payload_mass"),
                        (("--payload-mass", "1", "--payload-com", "0,0,0.9"), "payload_com"),
                        (("--payload-mass", "1", "--payload-inertia", "1,1,3,0,0,0"), "payload_inertia"),
                        (("--body-size", "female_42"), "female_42"),
                        (("--side", "middle"), "--side")):
        r = run(*args)
        assert r.returncode == 2, (args, r.stderr)
        assert words in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("how,domain", [
    ({"args": ["ROS_DOMAIN_ID=42"]}, "42"), ({"env": {"ROS_DOMAIN_ID": "44"}}, "44"),
    ({"env": {"ROS_DOMAIN_ID": "0"}}, "73"), ({}, "73")])
def test_make_demo_takes_another_domain(how, domain):
    """`make demo` ran in domain 73 whatever the user asked (hard-coded in the recipe)."""
    # not as a sub-make of `make test` (CI): MAKELEVEL/MAKEFLAGS would make it print
    # "make[1]: Entering directory" around the recipe and pass make test's own variables
    drop = {"ROS_DOMAIN_ID", "MAKELEVEL", "MAKEFLAGS", "MFLAGS"}
    env = {k: v for k, v in os.environ.items() if k not in drop} | how.get("env", {})
    r = subprocess.run(["make", "--no-print-directory", "-n", "demo", *how.get("args", [])],
                       cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert f"ROS_DOMAIN_ID={domain} " in r.stdout.splitlines()[-1], r.stdout


def test_demo_refuses_a_param_that_is_not_name_value(capsys):
    """`demo --param` passes torque_node parameters; anything but NAME:=VALUE is one line,
    exit 2, before any process starts."""
    from forearm_dynamics.cli import demo

    assert demo.main(["--param", "qos_depth=5000", "--out", "/nonexistent/never"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["demo: --param 'qos_depth=5000' is not NAME:=VALUE (e.g. qos_depth:=5000)"]
