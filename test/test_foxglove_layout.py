"""config/foxglove_layout.json: generated from the joint table (never hand-edited), one
torque plot per DOF group covering every joint once by its index, the ±2σ band paths on the
user script's output, the 3D panel on arm_markers in the frame arm_viz draws in."""

from __future__ import annotations

import json
import re

import pytest

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.description import DOF_GROUPS
from forearm_dynamics.paths import config_file
from forearm_dynamics.viz import ArmScene, foxglove_layout

pytestmark = pytest.mark.unit


def test_the_committed_layout_is_the_generated_one():
    assert config_file("foxglove_layout.json").read_text(encoding="utf-8") == foxglove_layout.text()


def test_plots_cover_every_joint_once_in_its_group():
    cfg = json.loads(foxglove_layout.text())["configById"]
    seen = []
    for group, joints in DOF_GROUPS.items():
        paths = cfg[f"Plot!{group}"]["paths"]
        torques = [p for p in paths if p["value"].startswith("/joint_torques.")]
        idx = [int(re.fullmatch(r"/joint_torques\.effort\[(\d+)\]", p["value"]).group(1))
               for p in torques]
        assert [JOINT_NAMES[i] for i in idx] == list(joints)
        assert [p["label"].split()[0] for p in torques] == list(joints)
        band = [p["value"] for p in paths if p["value"].startswith(foxglove_layout.BAND_TOPIC)]
        assert band == [f"{foxglove_layout.BAND_TOPIC}.{s}[{i}]" for i in idx
                        for s in ("lower", "upper")]
        seen += idx
    assert sorted(seen) == list(range(len(JOINT_NAMES)))


def test_the_3d_panel_and_script_use_the_topics_and_frame_we_write():
    lay = json.loads(foxglove_layout.text())
    three_d = lay["configById"]["3D!arm"]
    for kind, side in (("segmented", "right"), ("anatomical", "left"), ("solid", "right")):
        assert three_d["followTf"] == ArmScene(build_model(kind, 50, side=side)).root_frame
    assert list(three_d["topics"]) == ["/arm_markers"]
    script = lay["userNodes"]["joint_torques_2sigma"]["sourceCode"]
    assert 'inputs = ["/joint_torques", "/joint_torques_std"]' in script
    assert f'output = "{foxglove_layout.BAND_TOPIC}"' in script
    assert lay["configById"]["DiagnosticSummary!diagnostics"]["topicToRender"] == "/diagnostics"
    # every panel in the mosaic is configured, and every configured panel is placed
    placed = re.findall(r'"([A-Za-z0-9]+![a-z_]+)"', json.dumps(lay["layout"]))
    assert sorted(placed) == sorted(lay["configById"])
