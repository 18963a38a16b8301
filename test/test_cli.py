"""export_urdf as a user runs it: a real process, a real file."""

import subprocess
import sys

import numpy as np
import pinocchio as pin

from forearm_dynamics import build_model


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
