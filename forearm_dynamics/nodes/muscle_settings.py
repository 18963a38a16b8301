"""muscle_node's parameters (ROS-free) and the muscle bundle one sample is solved with.

The model parameters are the torque node's own definitions (torque_config.MODEL_SPECS, as
arm_viz takes them: the estimator aside), used until a torque node states its model on its
config topic; then that config rules and every live change of it (body size, side, payload,
model) rebuilds the muscle model. A payload changes the torques (the input), not the muscles:
it rebuilds all the same, so the config this node states always names the model in force.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..muscles import MuscleModel, StaticOptimizer, load_muscle_model
from .arm_viz_settings import MODEL_NAMES, VIZ_MODEL_SPECS, own_model
from .spec import ParameterError, Settings, Spec

MUSCLE_SPECS = (
    Spec("input_topic", "joint_torques", "JointState input: the torque node's output (position, "
         "velocity and effort = torque by joint name)"),
    Spec("output_topic", "muscle_forces", "JointState output, one per input sample that is not "
         "decimated, same header: name = muscles, position = activation (0..1), velocity = "
         "muscle-tendon lengthening speed (m/s), effort = tendon force (N)"),
    Spec("reserves_topic", "muscle_reserves", "JointState output beside output_topic (same "
         "header): name = joints, effort = the reserve torque of each joint (N*m): what the "
         "muscles could not carry; position and velocity empty; '' = not published (one "
         "message per sample instead of two: ~half the publish cost)"),
    Spec("config_topic", "torque_node/config", "the torque node's config topic (JSON, latched): "
         "its model, side and body size replace this node's own model parameters, following "
         "every live change; '' = never listen"),
    Spec("muscle_model", "", "muscle model file (JSON, forearm_dynamics.muscles/1, made by "
         "python -m forearm_dynamics.muscles.fit from a MuJoCo model or "
         "python -m forearm_dynamics.muscles.source_osim from an OpenSim .osim); '' = the "
         "shipped MyoArm-derived model (Apache-2.0)"),
    Spec("decimation", 1, "solve and publish one input sample in every `decimation` (1 = every "
         "sample); the others are counted, not answered", "", 1, 1000),
    Spec("reserve_optimal_torque", 1.0, "optimal torque of each joint's reserve actuator: the cost "
         "of a reserve torque r is (r / this)^2 beside each activation squared (OpenSim SO's "
         "weighting)", "N*m", 1e-3, 1e3),
    Spec("reserve_warn", 0.5, "a sample whose largest |reserve| exceeds this counts as reserve use "
         "in /diagnostics", "N*m", 0.0, 1e3),
    Spec("force_velocity", True, "muscle force-velocity from the path's lengthening speed (false: "
         "isometric force-length only)"),
    Spec("passive", False, "subtract the passive fibre forces' torques before the QP (false: "
         "like OpenSim's static optimisation, which leaves them out)"),
    Spec("qos_depth", 1000, "history depth of the outputs", "messages", 1, 100000),
    Spec("input_depth", 5000, "history depth of the joint_torques input (best effort by "
         "default): how far (samples) this node may fall behind in a CPU stall before a sample "
         "is lost; 5000 = 5 s at 1 kHz, the most Fast DDS keeps for a reader (its default "
         "resource limit max_samples: python -m benchmarks.reader_depth). With 1000 the backlog "
         "reached 1 s and 2 606 of 97 500 samples were dropped (benchmarks/muscle_node.py, "
         "load 1-3.6)", "messages", 1, 100000),
    Spec("backlog_limit", 60000, "samples this node queues itself when it falls behind: while "
         "it works it takes what has arrived out of the DDS reader (whose queue stops at 5000, "
         "input_depth) every 5 ms and answers it in order; past this many the oldest are dropped "
         "and counted (backlog_dropped_total in /diagnostics). ~1 KB a sample (60000: 60 s at "
         "1 kHz). 0 = no queue of its own: the DDS reader's alone (the node before 2026-12: "
         "2 203 of 97 500 lost in a chain at load 2-4)", "samples", 0, 10000000),
    Spec("qos_reliable", True, "reliable (true) or best-effort (false) outputs"),
    Spec("input_reliable", False, "reliable (true) or best-effort (false) joint_torques input. "
         "Best effort by default so the torque path never waits for the muscles: a reliable "
         "reader that falls behind fills the torque node's writer history and its publish() "
         "then blocks (measured, benchmarks/muscle_node.py at load 11-17: joint_torques latency "
         "p50 752 ms with a reliable muscle_node behind, 0.88 ms without). On loopback a best-"
         "effort reader loses samples only when this node cannot keep up"),
    Spec("executor", "events", "rclpy executor: events (EventsExecutor) or single",
         choices=("events", "single")),
    Spec("nice", 10, "niceness this process takes at start-up (Linux, 0 = unchanged): on a busy "
         "machine the torque path keeps the CPU first and this node takes what is left", "", 0, 19),
    Spec("diagnostics_period", 1.0, "time between /diagnostics messages; 0 = none", "s", 0.0, 3600.0),
)

SPECS = (*MUSCLE_SPECS, *VIZ_MODEL_SPECS)


@dataclass(frozen=True)
class MuscleSettings(Settings):
    """The read-only parameters (MUSCLE_SPECS), read once at start-up."""

    input_topic: str
    output_topic: str
    reserves_topic: str
    config_topic: str
    muscle_model: str
    decimation: int
    reserve_optimal_torque: float
    reserve_warn: float
    force_velocity: bool
    passive: bool
    qos_depth: int
    input_depth: int
    backlog_limit: int
    qos_reliable: bool
    input_reliable: bool
    executor: str
    nice: int
    diagnostics_period: float


@dataclass(frozen=True)
class MuscleBundle:
    """Everything one sample is solved with; swapped whole on a model change."""

    config_id: int
    model: MuscleModel
    optimizer: StaticOptimizer
    geometry: tuple  # model.geometry_outputs(): R, L, V written per sample (solve_sample_into)
    source: str  # "own parameters" or the torque node's config topic
    arm_summary: dict  # model kind, body size, side, payload of the arm it is for
    build_ms: float


def build_bundle(settings: MuscleSettings, config_id: int, body_size: Any, side: str,
                 source: str, arm_summary: dict) -> MuscleBundle:
    """Load (scale) the muscle model and make its optimizer; MuscleModelError if refused."""
    t0 = time.perf_counter()
    mm = load_muscle_model(settings.muscle_model or None, side=side, body_size=body_size)
    so = StaticOptimizer(mm, reserve_optimal_torque=settings.reserve_optimal_torque,
                         passive=settings.passive, velocity=settings.force_velocity)
    # first-call costs (numpy paths, the QP's set-up, binding the compiled step to the
    # geometry's arrays) here, not on the first sample it solves
    nj, geo = len(mm.joint_names), mm.geometry_outputs()
    zero = np.zeros(nj)
    so.solve_sample_into(zero, zero, zero, geo, np.empty(mm.n), np.empty(mm.n), np.empty(nj))
    so.reset()
    return MuscleBundle(config_id, mm, so, geo, source, arm_summary,
                        (time.perf_counter() - t0) * 1e3)


def arm_summary(arm) -> dict:
    return {"model": arm.kind, "body_size": arm.body_size.label, "side": arm.side,
            "payload_kg": 0.0 if arm.payload is None else float(arm.payload.mass)}


def own_arm(values: dict[str, Any]):
    """The arm of this node's own model parameters (ParameterError naming the problem)."""
    return own_model({k: values[k] for k in MODEL_NAMES})


__all__ = ["MODEL_NAMES", "MUSCLE_SPECS", "SPECS", "MuscleBundle", "MuscleSettings",
           "ParameterError", "arm_summary", "build_bundle", "own_arm"]
