"""bag_muscles' work: the muscle node's outputs for every joint_torques message of a bag.

The same computation as muscle_node, sample by sample in the bag's order (the same
StaticOptimizer, warm-started from the previous sample; the QP's optimum is unique, so the
warm start changes the time, not the answer): `muscle_forces` (name = muscles, position =
activation, velocity = muscle-tendon lengthening speed m/s, effort = force N),
`muscle_reserves` (name = joints, effort = reserve N·m), same header and log time as the
torques they answer, and a `muscle_node/config` JSON like the node's. The arm is the one the
bag's torque_node/config names (body size, side), else the caller's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..bag.reader import open_bag
from ..codec.jointstate import JointSeries, read_joint_series
from ..codec.jointstate_cdr import OutputTemplate, StdTemplate
from ..description import JOINT_NAMES
from ..errors import ForeignBag, OutputExists
from ..model_config import model_from_config
from ..muscles import MuscleModel, StaticOptimizer, load_muscle_model
from ..version import package_version
from .outputs import CONFIG, JOINT_STATE, copy_with_outputs
from .recording import read_config


@dataclass
class MuscleResult:
    stamps_ns: np.ndarray
    log_ns: np.ndarray
    frame_ids: list[str]
    activations: np.ndarray  # (N, n)
    speeds: np.ndarray  # (N, n) m/s
    forces: np.ndarray  # (N, n) N
    reserves: np.ndarray  # (N, 20) N·m
    infeasible: np.ndarray  # (N,) bool
    solve_s: np.ndarray  # (N,) s
    dropped: int = 0
    decimated: int = 0
    warnings: list[str] = field(default_factory=list)


def compute(stream: JointSeries, mm: MuscleModel, *, reserve_optimal_torque: float = 1.0,
            force_velocity: bool = True, passive: bool = False, decimation: int = 1) -> MuscleResult:
    """Every message with finite q, q̇, τ of every joint (as the node: others are dropped),
    one in `decimation` of them solved (the node's counting)."""
    ok = (np.isfinite(stream.position).all(axis=1) & np.isfinite(stream.velocity).all(axis=1)
          & np.isfinite(stream.effort).all(axis=1))
    warnings = []
    if not ok.all():
        warnings.append(f"{int((~ok).sum())} messages without a finite position, velocity and "
                        "effort for every joint dropped (as the node rejects them)")
    idx = np.flatnonzero(ok)
    solved = idx[::decimation]
    so = StaticOptimizer(mm, reserve_optimal_torque=reserve_optimal_torque, passive=passive,
                         velocity=force_velocity)
    n, N = mm.n, len(solved)
    a, f, sp = np.empty((N, n)), np.empty((N, n)), np.empty((N, n))
    r, inf, st = np.empty((N, len(JOINT_NAMES))), np.zeros(N, bool), np.empty(N)
    geo = mm.geometry_outputs()
    for k, i in enumerate(solved):  # the node's own per-sample path (solve_sample_into)
        q, qd, tau = stream.position[i], stream.velocity[i], stream.effort[i]
        _flag, inf[k], st[k] = so.solve_sample_into(q, qd, tau, geo, a[k], f[k], r[k])
        sp[k] = geo[2]
    return MuscleResult(stream.stamp_ns[solved], stream.log_ns[solved],
                        [stream.frame_ids[i] for i in solved], a, sp, f, r, inf, st,
                        int((~ok).sum()), len(idx) - N, warnings)


def write_bag(src: Path, dst: Path, res: MuscleResult, mm: MuscleModel, config: dict,
              output_topic: str, reserves_topic: str, config_topic: str,
              overwrite: bool = False) -> dict[str, int]:
    """Every message of src plus the two outputs and the config; counts per topic."""
    bag = open_bag(src)
    info = bag.info
    for topic in (output_topic, reserves_topic, config_topic):
        if (ch := info.find_topic(topic)) is not None:
            raise OutputExists(f"{src} already has {ch.topic}; choose another with --topic")
    templates: dict[str, tuple[OutputTemplate, StdTemplate]] = {}

    def emit(k: int, writer, channels: dict[str, int]) -> None:
        fid = res.frame_ids[k]
        if fid not in templates:
            templates[fid] = (OutputTemplate(mm.names, fid), StdTemplate(JOINT_NAMES, fid))
        tpl, rt = templates[fid]
        tpl.q[:] = res.activations[k]
        tpl.qd[:] = res.speeds[k]
        tpl.effort[:] = res.forces[k]
        sec_nsec = divmod(int(res.stamps_ns[k]), 1_000_000_000)
        tpl.pack_stamp(*sec_nsec)
        writer.write(channels[output_topic], tpl.payload(), int(res.log_ns[k]))
        writer.write(channels[reserves_topic], rt.fill(*sec_nsec, res.reserves[k]),
                     int(res.log_ns[k]))

    kinds = [(output_topic, JOINT_STATE), (reserves_topic, JOINT_STATE), (config_topic, CONFIG)]
    return copy_with_outputs(bag, dst, kinds, config, res.log_ns, emit, overwrite=overwrite)


def bag_muscles(src: Path, dst: Path, *, muscle_model: str | None = None, body_size=50,
                side: str = "right", input_topic: str = "joint_torques",
                output_topic: str = "muscle_forces", reserves_topic: str = "muscle_reserves",
                reserve_optimal_torque: float = 1.0, force_velocity: bool = True,
                passive: bool = False, decimation: int = 1,
                overwrite: bool = False) -> tuple[MuscleResult, dict, dict]:
    """(result, counts per topic, config) of a bag's joint_torques."""
    src, dst = Path(src), Path(dst)
    if dst.exists() and src.resolve() == dst.resolve():
        raise OutputExists(f"{dst}: the output must be another file than the input")
    bag = open_bag(src)
    stream = read_joint_series(bag, input_topic, JOINT_NAMES, effort=True)
    if not np.isfinite(stream.effort).any():
        raise ForeignBag(f"{src}: {stream.topic} carries no effort: not joint torques")
    cfg, warnings = read_config(bag)
    source = "arguments"
    if cfg is not None:
        try:
            arm = model_from_config(cfg).arm
            body_size, side, source = arm.body_size, arm.side, "torque_node/config"
        except (ValueError, TypeError, KeyError) as exc:
            warnings.append(f"torque_node/config not used ({str(exc).splitlines()[0]}); "
                            "the arguments' body size and side instead")
    mm = load_muscle_model(muscle_model, side=side, body_size=body_size)
    t0 = time.perf_counter()
    res = compute(stream, mm, reserve_optimal_torque=reserve_optimal_torque,
                  force_velocity=force_velocity, passive=passive, decimation=decimation)
    res.warnings[:0] = warnings
    if not bag.info.complete:
        res.warnings.insert(0, f"{src} is truncated ({bag.info.problem}); using its complete chunks")
    config = {
        "node": "bag_muscles", "version": package_version(), "config_id": 1,
        "applies_from_stamp_ns": 0, "input_topic": stream.topic, "output_topic": output_topic,
        "reserves_topic": reserves_topic, "source_bag": str(src), "model_source": source,
        "muscles": mm.config(),
        "solver": {"method": "static optimisation per sample, daqp (warm-started)",
                   "reserve_optimal_torque": reserve_optimal_torque,
                   "force_velocity": force_velocity, "passive": passive, "tendon": "rigid"},
        "decimation": decimation, "compute_s": round(time.perf_counter() - t0, 3),
    }
    ns = stream.topic.rsplit("/", 1)[0]
    topics = [t if t.startswith("/") else f"{ns}/{t}"
              for t in (output_topic, reserves_topic, "muscle_node/config")]
    counts = write_bag(src, dst, res, mm, config, *topics, overwrite=overwrite)
    return res, counts, config
