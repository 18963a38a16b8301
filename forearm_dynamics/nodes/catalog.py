"""Every node's parameters, generated from their Specs: config/nodes/<node>.yaml and docs/nodes.md.

    python -m forearm_dynamics.nodes.catalog --write   # after changing a Spec
    python -m forearm_dynamics.nodes.catalog --check   # exit 1 if a committed file differs

The Specs (spec.py) are the one source of each parameter's default, unit, range and
description; the parameter files the nodes read their defaults from and the reference page
are written from them, never by hand (test/test_node_catalog.py compares, values included).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

import yaml

from .spec import Spec

#: node name -> (module, attribute holding its Spec table, one line on what it does).
NODES: dict[str, tuple[str, str, str]] = {
    "torque_node": ("forearm_dynamics.nodes.torque_node", "TorqueNode.specs",
                    "joint_states -> joint_torques: inverse dynamics of the forearm-hand model"),
    "null_echo_node": ("forearm_dynamics.nodes.stream_node", "STREAM_SPECS",
                       "the torque node's pipeline without the dynamics (a baseline for latency)"),
    "trajectory_publisher": ("forearm_dynamics.nodes.trajectory_publisher", "SPECS",
                             "the paper's movements as a joint_states stream, with markers"),
    "bag_recorder": ("forearm_dynamics.nodes.bag_recorder", "SPECS",
                     "records topics into an MCAP bag that ros2 bag and rosbags read"),
    "bag_player": ("forearm_dynamics.nodes.bag_player", "SPECS",
                   "plays a bag's topics at their recorded timing"),
    "arm_sim": ("forearm_dynamics.nodes.arm_sim_settings", "SPECS",
                "the virtual arm: joint_commands torques -> forward dynamics -> joint_states"),
    "arm_viz": ("forearm_dynamics.nodes.arm_viz_settings", "SPECS",
                "arm markers (MarkerArray) from joint_torques and the torque node's config"),
    "muscle_node": ("forearm_dynamics.nodes.muscle_settings", "SPECS",
                    "joint_torques -> muscle_forces: static optimisation of every torque sample"),
}

#: executables that take another node's parameters (the same Specs, the same config file)
SAME_PARAMETERS: dict[str, str] = {
    "torque_lifecycle_node": "torque_node",  # the managed torque node (nodes/lifecycle.py)
}

ROOT = Path(__file__).resolve().parents[2]
COMMAND = "python -m forearm_dynamics.nodes.catalog --write"


def specs_of(node: str) -> tuple[Spec, ...]:
    module, attr = NODES[node][:2]
    obj = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return tuple(obj)


def _value(value) -> str:
    """`value` as YAML on one line (flow style: a list as [a, b])."""
    text = yaml.safe_dump([value], default_flow_style=True, width=10_000, allow_unicode=True).strip()
    return text[1:-1]


def _comment(text: str, indent: str, width: int = 96) -> list[str]:
    words, lines, line = text.split(), [], ""
    for w in words:
        if line and len(indent) + 2 + len(line) + 1 + len(w) > width:
            lines.append(line)
            line = w
        else:
            line = f"{line} {w}" if line else w
    if line:
        lines.append(line)
    return [f"{indent}# {x}" for x in lines]


def render_yaml(node: str, specs: tuple[Spec, ...]) -> str:
    out = [
        f"# {node} parameters: {NODES[node][2]}.",
        "# GENERATED from the node's Spec table (forearm_dynamics/nodes) by",
        f"#   {COMMAND}",
        "# Edit the Spec, not this file (test/test_node_catalog.py compares them).",
        "# The node reads its defaults from this file as installed (share/forearm_dynamics/config/",
        "# nodes); override them with -p name:=value or a --params-file of your own, keyed `/**:`",
        "# like this one so that a renamed node still reads it. `ros2 param describe` shows the",
        "# same texts. A refused value at start-up: one line naming the parameter, exit code 2.",
        "/**:",
        "  ros__parameters:",
    ]
    for s in specs:
        out += _comment(s.text(), "    ")
        out.append(f"    {s.name}: {_value(s.default)}")
    return "\n".join(out) + "\n"


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def render_docs(nodes: dict[str, tuple[Spec, ...]]) -> str:
    out = [
        "# Nodes and their parameters",
        "",
        f"Generated from the nodes' Spec tables by `{COMMAND}` (checked by",
        "test/test_node_catalog.py): every parameter with its default, unit and description.",
        "Each node reads its defaults from `config/nodes/<node>.yaml` (generated from the same",
        "tables); set one with `-p name:=value` or a `--params-file` keyed `/**:`.",
        "",
    ]
    for node in nodes:
        out.append(f"- [{node}](#{node}): {NODES[node][2]}")
    for node, specs in nodes.items():
        what = NODES[node][2]
        out += ["", f"## {node}", "", f"{what[0].upper()}{what[1:]}. Defaults: `config/nodes/{node}.yaml`.",
                "",
                "| parameter | default | unit | runtime | description |", "|---|---|---|---|---|"]
        for s in specs:
            default = _value(s.default)
            out.append(f"| `{s.name}` | `{_cell(default)}` | {_cell(s.unit)} | "
                       f"{'live' if s.live else 'start-up'} | {_cell(s.text())} |")
    return "\n".join(out) + "\n"


def expected() -> dict[Path, str]:
    """Every generated file (path in the checkout) and its text."""
    tables = {node: specs_of(node) for node in NODES}
    files = {ROOT / "config" / "nodes" / f"{n}.yaml": render_yaml(n, s) for n, s in tables.items()}
    files[ROOT / "docs" / "nodes.md"] = render_docs(tables)
    return files


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="catalog", description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", action="store_true", help="write the generated files")
    mode.add_argument("--check", action="store_true", help="exit 1 if a committed file differs")
    args = ap.parse_args(argv)
    stale = []
    for path, text in expected().items():
        if path.is_file() and path.read_text(encoding="utf-8") == text:
            continue
        if args.write:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
            print(f"wrote {path.relative_to(ROOT)}")
        else:
            stale.append(str(path.relative_to(ROOT)))
    if stale:
        print(f"catalog: out of date (run `{COMMAND}`): {', '.join(stale)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
