"""The config message torque_node states (nodes/torque_config.py) and its strict reader
(model_config.py): exactly what was built, for every model, read back to the same
torques; anything unexpected refused with the key named; the config in force per stamp."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from forearm_dynamics import build_model
from forearm_dynamics.model_config import config_in_force, model_config, model_from_config
from forearm_dynamics.nodes.params import ParameterError
from forearm_dynamics.nodes.torque_config import ModelRequest, build_bundle

pytestmark = pytest.mark.unit

RNG = np.random.default_rng(5)
Q, QD, QDD = (RNG.uniform(-1, 1, 20) for _ in range(3))


@pytest.mark.parametrize("kind", ["segmented", "solid", "anatomical"])
@pytest.mark.parametrize("size", [5, 95])
def test_every_model_round_trips(kind: str, size: int) -> None:
    arm = build_model(kind, size)
    cfg = json.loads(json.dumps(model_config(arm)))
    back = model_from_config(cfg)
    np.testing.assert_array_equal(back.arm.inverse_dynamics(Q, QD, QDD), arm.inverse_dynamics(Q, QD, QDD))
    assert back.percentile == size and back.arm.kind == kind


def test_solid_config_states_the_solid_axis() -> None:
    """The solid model turns about the cylinder's own axis: its config says so (it used to
    carry the segmented model's offsets, which a reader then had to drop)."""
    cfg = model_config(build_model("solid", 50))
    assert cfg["placement"] == {"name": "solid", "split": 0.0, "split_rule": "fixed",
                                "axis_offset_proximal": [0.0, 0.0],
                                "axis_offset_distal": [0.0, 0.0], "cylinder": "uniform"}
    seg = model_config(build_model("segmented", 50, split=0.3))
    # a split given explicitly is stated, as a custom placement
    assert seg["placement"]["split"] == 0.3 and seg["placement"]["name"] == "custom"
    assert seg["placement"]["axis_offset_distal"] != [0.0, 0.0]
    paper = model_config(build_model("segmented", 95, placement="paper"))["placement"]
    assert paper["name"] == "paper" and paper["split_rule"] == "radius_inertia"
    assert model_config(build_model("anatomical", 50))["placement"] is None


@pytest.mark.parametrize("kw", [
    {"placement": "paper"}, {"placement": "parallel"}, {"cylinder": "mass_matched"},
    {"side": "left"}, {"side": "left", "payload_mass": 0.4},
    {"payload_mass": 1.2, "payload_com": (0.01, -0.07, -0.04),
     "payload_inertia": (2e-3, 1e-3, 2e-3, 0, 0, 0)},
    {"split": 0.4, "axis_offset_distal": (-0.01, 0.002)},
])
@pytest.mark.parametrize("size", [5, "female_95"])
def test_personal_and_placed_models_round_trip(kw: dict, size) -> None:
    """Side, payload and every placement are stated and rebuilt exactly, at any body size
    (offsets are published at that size: the reader must not scale them twice)."""
    arm = build_model("segmented", size, **kw)
    cfg = json.loads(json.dumps(model_config(arm)))
    back = model_from_config(cfg).arm
    np.testing.assert_allclose(back.inverse_dynamics(Q, QD, QDD), arm.inverse_dynamics(Q, QD, QDD),
                               rtol=0, atol=1e-12)
    assert back.side == arm.side


def test_a_placement_this_core_would_build_differently_is_refused() -> None:
    cfg = model_config(build_model("segmented", 50, placement="parallel"))
    cfg["placement"]["axis_offset_distal"][0] += 1e-4
    with pytest.raises(ValueError, match="placement differs"):
        model_from_config(cfg)


def test_a_split_survives_the_round_trip() -> None:
    arm = build_model("segmented", 50, split=0.3)
    back = model_from_config(json.loads(json.dumps(model_config(arm)))).arm
    np.testing.assert_array_equal(back.inverse_dynamics(Q, QD, QDD), arm.inverse_dynamics(Q, QD, QDD))
    # and it matters: the default split gives other torques
    assert np.abs(build_model("segmented", 50).inverse_dynamics(Q, QD, QDD)
                  - arm.inverse_dynamics(Q, QD, QDD)).max() > 1e-6


@pytest.mark.parametrize("edit, key", [
    (lambda c: c.update(simplified={}), "simplified"),  # the old format's key: unknown
    (lambda c: c.pop("placement"), "placement"),
    (lambda c: c.pop("joint_names"), "joint_names"),
    (lambda c: c["body_size"].update(extra=1.0), "extra"),
    (lambda c: c["body_size"].pop("mass"), "mass"),
    (lambda c: c["placement"].update(tilt=0.1), "tilt"),
    (lambda c: c.update(side="middle"), "side"),
    (lambda c: c.update(schema=1), "schema"),
    (lambda c: c.update(joint_names=c["joint_names"][::-1]), "joint_names"),
])
def test_the_reader_is_strict(edit, key: str) -> None:
    cfg = copy.deepcopy(model_config(build_model("segmented", 50)))
    edit(cfg)
    with pytest.raises(ValueError, match=key):
        model_from_config(cfg)


def test_config_in_force_per_stamp() -> None:
    base = model_config(build_model("segmented", 50))
    c1 = {**base, "config_id": 1, "applies_from_stamp_ns": 0}
    c2_built = {**base, "config_id": 2, "applies_from_stamp_ns": None}
    c2 = {**base, "config_id": 2, "applies_from_stamp_ns": 1000}
    c3 = {**base, "config_id": 3, "applies_from_stamp_ns": 5000}
    log = [(1, c1), (2, c2_built), (3, c1), (4, c2), (5, c3), (6, c2)]  # periodic repeats too
    assert config_in_force(log, 999)["config_id"] == 1
    assert config_in_force(log, 1000)["config_id"] == 2
    assert config_in_force(log, 4999)["config_id"] == 2
    assert config_in_force(log, 5000)["config_id"] == 3
    assert config_in_force([(2, c2_built)], 10**12) is None  # built, never applied
    assert config_in_force([(1, base)], 7)["model"] == "segmented"  # a model-only config


def test_live_request_validation_speaks_ros_parameters() -> None:
    values = {"model": "segmented", "body_size": 50, "side": "right", "payload_mass": 0.0,
              "payload_com": [0.0, 0.0, 0.0], "payload_inertia": [0.0] * 6, "placement": "",
              "stature": 0.0, "body_mass": 0.0, "forearm_length": 0.0, "hand_length": 0.0,
              "hand_breadth": 0.0, "split": -1.0, "estimator": "backward",
              "estimator.accel_cutoff_hz": 0.0, "estimator.velocity_cutoff_hz": 0.0}
    req = ModelRequest.from_values(values)
    assert req.build_kwargs() == {}  # defaults pass no keyword: the core's defaults apply
    for change, name in [({"body_size": "fifty"}, "body_size"), ({"body_mass": 80.0}, "stature"),
                         ({"stature": 1.8}, "body_mass"), ({"split": -0.5}, "split"),
                         ({"model": "anatomical", "split": 0.5}, "split"),
                         ({"payload_com": [0.1]}, "payload_com"),
                         ({"payload_mass": 80.0}, "payload_mass"),
                         ({"payload_mass": 0.5, "payload_com": [0.4, 0.4, 0.0]}, "payload_com"),
                         ({"payload_inertia": [1e-3, 0, 0, 0, 0, 0]}, "payload_inertia")]:
        with pytest.raises(ParameterError) as exc:
            ModelRequest.from_values({**values, **change})
        assert exc.value.name == name and "dict" not in str(exc.value), str(exc.value)
    assert ModelRequest.from_values({**values, "body_size": "95"}).body_size == 95
    b1 = build_bundle(req, 1, 20)
    b2 = build_bundle(ModelRequest.from_values({**values, "body_size": 95}), 2, 20, b1)
    assert b2.estimator is b1.estimator  # model only: the estimator keeps its history
    b3 = build_bundle(ModelRequest.from_values({**values, "estimator.accel_cutoff_hz": 5.0}), 3, 20, b2)
    assert b3.estimator is not b2.estimator and b3.estimator.values["accel_cutoff_hz"] == 5.0


def test_every_writer_writes_what_the_reader_reads(tmp_path) -> None:
    """bag_torques' config (with its source_bag) is read back by the one reader: the message
    is written and read by model_config.py alone (the `source_bag` refusal of issue 17)."""
    from forearm_dynamics.offline.torques import config_message as offline_config

    arm = build_model("solid", 95, side="left")
    for estimator in ("backward", "zero_phase"):
        cfg = json.loads(json.dumps(offline_config(arm, estimator, None, tmp_path / "in.mcap",
                                                   "/joint_states", "/joint_torques", 0.1, None)))
        assert cfg["source_bag"] == str(tmp_path / "in.mcap") and cfg["node"] == "bag_torques"
        back = model_from_config(cfg).arm
        np.testing.assert_array_equal(back.inverse_dynamics(Q, QD, QDD), arm.inverse_dynamics(Q, QD, QDD))


def test_the_writer_refuses_a_key_the_reader_would_refuse() -> None:
    from forearm_dynamics.model_config import NODE_KEYS, config_message

    part = model_config(build_model("segmented", 50))
    with pytest.raises(KeyError, match="source_bags"):
        config_message(part, node="x", source_bags="typo")
    full = config_message(part, **dict.fromkeys(NODE_KEYS, None))
    assert set(full) == set(part) | NODE_KEYS
