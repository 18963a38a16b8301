"""Where parameters come from (real processes): the defaults are config/nodes/<node>.yaml's (the
file the package installs; FOREARM_DYNAMICS_CONFIG points a test at a copy), a params file
keyed `/**:` reaches a renamed node, and the config topic is the node's own (`~/config`),
so two torque nodes in two namespaces do not collide."""

from __future__ import annotations

import json
import shutil
import signal
from pathlib import Path

import pytest
import rosproc
import yaml
from rcl_interfaces.srv import GetParameters
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from forearm_dynamics.nodes import arm_sim_settings, arm_viz_settings, bag_recorder, trajectory_publisher
from forearm_dynamics.nodes.params import load_defaults
from forearm_dynamics.nodes.stream_node import STREAM_SPECS
from forearm_dynamics.nodes.torque_node import TorqueNode
from forearm_dynamics.paths import config_dir

pytestmark = pytest.mark.ros

SPECS = {"torque_node": TorqueNode.specs, "trajectory_publisher": trajectory_publisher.SPECS,
         "null_echo_node": STREAM_SPECS, "bag_recorder": bag_recorder.SPECS,
         "arm_sim": arm_sim_settings.SPECS, "arm_viz": arm_viz_settings.SPECS}


def test_every_node_yaml_lists_its_parameters() -> None:
    """config/nodes/<node>.yaml names every parameter (its default), nothing else; only the
    estimator's method and settings may be left to the estimation package."""
    for node, specs in SPECS.items():
        keys = set(load_defaults(node))
        names = {s.name for s in specs}
        assert keys <= names, (node, keys - names)
        missing = {n for n in names - keys if not n.startswith("estimator")}
        assert not missing, (node, missing)


def _get(peer, node: str, names: list[str]) -> list:
    client = peer.node.create_client(GetParameters, f"{node}/get_parameters")
    try:
        assert client.wait_for_service(timeout_sec=rosproc.STARTUP_S), f"no {node}/get_parameters"
        future = client.call_async(GetParameters.Request(names=names))
        assert peer.spin_until(future.done, 10)
        return future.result().values
    finally:
        peer.node.destroy_client(client)


def test_defaults_files_renames_and_namespaces(tmp_path: Path, monkeypatch) -> None:
    conf = tmp_path / "config"
    shutil.copytree(config_dir(), conf)
    path = conf / "nodes" / "torque_node.yaml"
    path.write_text(path.read_text().replace("qos_depth: 1000", "qos_depth: 321"))
    mine = tmp_path / "mine.yaml"
    mine.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"body_size": 95}}}))
    monkeypatch.setenv("FOREARM_DYNAMICS_CONFIG", str(conf))
    a = rosproc.start("torque_node", "-r", "__ns:=/left_arm", "--params-file", str(mine))
    b = rosproc.start("torque_node", "-r", "__ns:=/right_arm", "-r", "__node:=arm_torques")
    peer = rosproc.Peer("params_test")
    try:
        got: dict[str, dict] = {}
        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        for topic in ("/left_arm/torque_node/config", "/right_arm/arm_torques/config"):
            peer.node.create_subscription(String, topic, lambda m, t=topic: got.__setitem__(
                t, json.loads(m.data)), qos)
        assert peer.spin_until(lambda: len(got) == 2, 20), (a.output(), b.output())
        assert got["/left_arm/torque_node/config"]["body_size"]["label"] == "p95"  # /** file
        assert got["/right_arm/arm_torques/config"]["body_size"]["label"] == "p50"
        assert got["/left_arm/torque_node/config"]["node"] == "/left_arm/torque_node"
        depth, size = _get(peer, "/left_arm/torque_node", ["qos_depth", "body_size"])
        assert depth.integer_value == 321  # the default came from the (copied) YAML
        assert size.integer_value == 95
        for p in (a, b):
            assert p.stop(signal.SIGINT) == 0, p.output()
            assert "summary: received 0, processed 0 (warm-up 0), rejected 0" in p.output()
    finally:
        peer.close()
        a.stop(signal.SIGINT)
        b.stop(signal.SIGINT)
