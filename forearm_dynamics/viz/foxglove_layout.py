"""config/foxglove_layout.json, generated: `python -m forearm_dynamics.viz.foxglove_layout`.

A Foxglove layout for a bag written by bag_viz (or a live arm_viz): the 3D panel showing
/arm_markers in the humerus frame (no TF needed), one Plot per DOF group of /joint_torques
(effort, by joint index in JOINT_NAMES order, labelled with the joint's name) with the
±2σ band when /joint_torques_std is there, and the /diagnostics summary. The band comes from
a Foxglove user script in the layout: it pairs each joint_torques_std message with the
joint_torques of the same stamp and publishes /studio_script/joint_torques_2sigma
(lower, upper); with no joint_torques_std the script publishes nothing and the plots show
the torques alone. Written from the joint table here so it cannot drift from JOINT_NAMES
(test_foxglove_layout checks the committed file equals this output).
"""

from __future__ import annotations

import json
import sys

from ..description import DOF_GROUPS, JOINT_NAMES

BAND_TOPIC = "/studio_script/joint_torques_2sigma"
ROOT_FRAME = "humerus"
#: Foxglove user script (TypeScript, run by Foxglove itself): tau +- 2 sigma per joint.
BAND_SCRIPT = """\
// forearm_dynamics: joint_torques +- 2 sigma (joint_torques_std: same header and names).
export const inputs = ["/joint_torques", "/joint_torques_std"];
export const output = "@BAND_TOPIC@";
type Stamp = { sec: number; nsec?: number; nanosec?: number };
type Joint = { header: { stamp: Stamp; frame_id: string }; name: string[]; effort: number[] };
type Out = { header: { stamp: Stamp; frame_id: string }; name: string[]; lower: number[]; upper: number[] };
const torques = new Map<string, number[]>();
const key = (s: Stamp) => `${s.sec}.${s.nanosec ?? s.nsec ?? 0}`;
export default function script(event: { topic: string; message: Joint }): Out | undefined {
  const m = event.message;
  if (event.topic === "/joint_torques") {
    torques.set(key(m.header.stamp), m.effort);
    if (torques.size > 2000) torques.delete(torques.keys().next().value as string);
    return undefined;
  }
  const tau = torques.get(key(m.header.stamp));
  if (tau === undefined) return undefined;
  return { header: m.header, name: m.name,
           lower: tau.map((t, i) => t - 2 * m.effort[i]),
           upper: tau.map((t, i) => t + 2 * m.effort[i]) };
}
""".replace("@BAND_TOPIC@", BAND_TOPIC)


def _plot(group: str, joints: tuple[str, ...]) -> dict:
    paths = []
    for name in joints:
        i = JOINT_NAMES.index(name)
        paths.append({"value": f"/joint_torques.effort[{i}]", "enabled": True,
                      "timestampMethod": "headerStamp", "label": f"{name} (N·m)"})
        for side in ("lower", "upper"):
            paths.append({"value": f"{BAND_TOPIC}.{side}[{i}]", "enabled": True,
                          "timestampMethod": "headerStamp", "label": f"{name} {side} 2σ",
                          "lineSize": 0.5})
    return {"title": f"{group} torque (N·m)", "paths": paths, "showLegend": True,
            "legendDisplay": "top", "showXAxisLabels": True, "showYAxisLabels": True,
            "isSynced": True, "xAxisVal": "timestamp", "followingViewWidth": 10}


def _column(ids: list[str]) -> dict | str:
    if len(ids) == 1:
        return ids[0]
    half = len(ids) // 2
    return {"direction": "column", "first": _column(ids[:half]), "second": _column(ids[half:]),
            "splitPercentage": 100.0 * half / len(ids)}


def layout() -> dict:
    plots = {f"Plot!{g}": _plot(g, joints) for g, joints in DOF_GROUPS.items()}
    config = {
        "3D!arm": {
            "followTf": ROOT_FRAME, "followMode": "follow-pose",
            "cameraState": {"distance": 1.2, "perspective": True, "phi": 60, "thetaOffset": 45,
                            "target": [0, -0.25, 0], "targetOffset": [0, 0, 0],
                            "targetOrientation": [0, 0, 0, 1], "fovy": 45, "near": 0.01,
                            "far": 100},
            "scene": {"enableStats": False},
            "topics": {"/arm_markers": {"visible": True}},
            "layers": {"grid": {"visible": True, "layerId": "foxglove.Grid", "frameId": ROOT_FRAME,
                                "size": 1, "divisions": 10, "lineWidth": 1,
                                "color": "#248eff66", "position": [0, 0, 0],
                                "rotation": [0, 0, 0]}},
            "transforms": {}, "publish": {"type": "point"}, "imageMode": {},
        },
        **plots,
        "DiagnosticSummary!diagnostics": {"topicToRender": "/diagnostics", "minLevel": 0,
                                          "pinnedIds": [], "hardwareIdFilter": "",
                                          "sortByLevel": True},
    }
    right = _column([*plots, "DiagnosticSummary!diagnostics"])
    return {
        "configById": config,
        "globalVariables": {},
        "userNodes": {"joint_torques_2sigma": {"name": "joint_torques_2sigma",
                                               "sourceCode": BAND_SCRIPT}},
        "playbackConfig": {"speed": 1},
        "layout": {"direction": "row", "first": "3D!arm", "second": right,
                   "splitPercentage": 45},
    }


def text() -> str:
    return json.dumps(layout(), indent=2, ensure_ascii=False) + "\n"


if __name__ == "__main__":
    sys.stdout.write(text())
