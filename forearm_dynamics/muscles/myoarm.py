"""MyoSuite's MyoArm (MuJoCo) at our joints: the source fit.py derives the shipped model from.

What is here: the joint mapping (`JOINT_MAP`, our angle = sign × MyoArm's) and the anatomical
actions it must reproduce (`SIGN_CHECKS`), the source itself (`MyoArm`: lengths, moment arms
from MuJoCo's tendon Jacobian, its own joint limits, the muscle parameters by MuJoCo's
definition), our joints' box and which joints each muscle crosses. Why a module of its own:
reading the source is one job, fitting it (fit.py, fit_core.py) and repairing its wrapping
artefacts (wrap_repair.py) others.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..description import JOINT_NAMES, load_description

#: our joint -> (MyoArm joint, sign): our angle = sign * MyoArm's angle.
JOINT_MAP: dict[str, tuple[str, int]] = {
    "elbow_flexion": ("elbow_flexion_r", 1),
    "pro_sup": ("pro_sup_r", 1),  # pronation positive in both (PT, PQ positive)
    "wrist_flexion": ("flexion_r", 1),
    "wrist_deviation": ("deviation_r", -1),  # MyoArm: radial positive (ECU, FCU negative)
    "thumb_cmc_flexion": ("cmc_flexion", -1),  # MyoArm: extension positive (EPB, EPL +)
    "thumb_cmc_abduction": ("cmc_abduction", 1),  # APL positive, EPL negative
    "thumb_mcp_flexion": ("mp_flexion_r", -1),  # MyoArm: FPL negative
    "thumb_ip_flexion": ("ip_flexion_r", -1),
    "index_mcp_flexion": ("mcp2_flexion_r", 1),
    "index_pip_flexion": ("pm2_flexion_r", 1),
    "index_dip_flexion": ("md2_flexion_r", 1),
    "middle_mcp_flexion": ("mcp3_flexion_r", 1),
    "middle_pip_flexion": ("pm3_flexion_r", 1),
    "middle_dip_flexion": ("md3_flexion", 1),
    "ring_mcp_flexion": ("mcp4_flexion_r", 1),
    "ring_pip_flexion": ("pm4_flexion", 1),
    "ring_dip_flexion": ("md4_flexion_r", 1),
    "little_mcp_flexion": ("mcp5_flexion_r", 1),
    "little_pip_flexion": ("pm5_flexion_r", 1),
    "little_dip_flexion": ("md5_flexion_r", 1),
}

#: Anatomical actions the mapping must reproduce (muscle, our joint, sign of moment arm).
SIGN_CHECKS = (
    ("BRA", "elbow_flexion", 1), ("TRIlat", "elbow_flexion", -1),
    ("PT", "pro_sup", 1), ("PQ", "pro_sup", 1), ("SUP", "pro_sup", -1),
    ("FCR", "wrist_flexion", 1), ("ECRB", "wrist_flexion", -1),
    ("ECU", "wrist_deviation", 1), ("FCU", "wrist_deviation", 1), ("ECRL", "wrist_deviation", -1),
    ("FPL", "thumb_ip_flexion", 1), ("EPL", "thumb_ip_flexion", -1),
    ("FPL", "thumb_mcp_flexion", 1), ("EPB", "thumb_mcp_flexion", -1),
    ("OP", "thumb_cmc_flexion", 1), ("EPB", "thumb_cmc_flexion", -1),
    ("EPL", "thumb_cmc_abduction", -1),  # APL: ~0 mm mid-range, sign not anatomical proof
    ("FDP2", "index_dip_flexion", 1), ("EDC3", "middle_mcp_flexion", -1),
)

#: Shoulder-only muscles of MyoArm: they cross no joint of ours.
SHOULDER_ONLY = ("DELT1", "DELT2", "DELT3", "SUPSP", "INFSP", "SUBSC", "TMIN", "TMAJ",
                 "PECM1", "PECM2", "PECM3", "LAT1", "LAT2", "LAT3", "CORB")

class MyoArm:
    """MuJoCo MyoArm at our joints: lengths and moment arms per muscle (tendon)."""

    def __init__(self, xml: Path | None = None):
        import mujoco

        if xml is None:
            import myo_sim

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                self.m = myo_sim.load_model("myoarm_r")
            self.version = {"myo_sim": myo_sim.__version__, "mujoco": mujoco.__version__}
        else:  # a user's MuJoCo model with MyoArm's joint and muscle names
            self.m = mujoco.MjModel.from_xml_path(str(xml))
            self.version = {"file": str(xml), "mujoco": mujoco.__version__}
        self.mujoco = mujoco
        m = self.m
        self.d = mujoco.MjData(m)
        jn = [m.joint(j).name for j in range(m.njnt)]
        self.qadr = np.array([m.jnt_qposadr[jn.index(JOINT_MAP[n][0])] for n in JOINT_NAMES])
        self.dofadr = np.array([m.jnt_dofadr[jn.index(JOINT_MAP[n][0])] for n in JOINT_NAMES])
        self.sign = np.array([JOINT_MAP[n][1] for n in JOINT_NAMES], float)
        names = [m.actuator(a).name for a in range(m.nu)]
        self.actuators = [a for a, n in enumerate(names) if n not in SHOULDER_ONLY]
        self.names = [names[a] for a in self.actuators]
        self.tendons = np.array([m.actuator_trnid[a, 0] for a in self.actuators])
        self._J = np.zeros((m.ntendon, m.nv))

    def evaluate(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q (N, 20) ours -> lengths (N, n) m, moment arms (N, n, 20) m (our signs)."""
        mj, m, d = self.mujoco, self.m, self.d
        q = np.atleast_2d(q)
        L = np.empty((len(q), len(self.names)))
        R = np.empty((len(q), len(self.names), 20))
        for k, qk in enumerate(q):
            d.qpos[:] = 0.0
            d.qpos[self.qadr] = self.sign * qk
            mj.mj_kinematics(m, d)
            mj.mj_comPos(m, d)
            mj.mj_tendon(m, d)
            mj.mju_sparse2dense(self._J, d.ten_J, m.ten_J_rownnz, m.ten_J_rowadr, m.ten_J_colind)
            L[k] = d.ten_length[self.tendons]
            R[k] = -self._J[self.tendons][:, self.dofadr] * self.sign
        return L, R

    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """The source's own joint limits at our joints (rad, our signs): past them (our wrist
        flexes to 80°, MyoArm's to 45°) its paths are geometry it was never built for."""
        m = self.m
        r = m.jnt_range[[m.jnt_qposadr.tolist().index(a) for a in self.qadr]] * self.sign[:, None]
        return r.min(axis=1), r.max(axis=1)

    def parameters(self, a_index: int) -> dict[str, float]:
        m = self.m
        a = self.actuators[a_index]
        g = m.actuator_gainprm[a]
        lo, hi = m.actuator_lengthrange[a]
        l0 = (hi - lo) / (g[1] - g[0])
        lts = lo - g[0] * l0
        if lts < 0.0:  # a fibre longer than its whole path (PQ, OP, RI3): no tendon instead,
            lts, l0 = 0.0, hi / g[1]  # the longest path puts the fibre at range[1]
        return {
            "max_isometric_force": float(g[2]),
            "optimal_fiber_length": float(l0),
            "tendon_slack_length": float(lts),
            "pennation_at_optimal": 0.0,
            "max_contraction_velocity": 10.0,
        }


def joint_box() -> tuple[np.ndarray, np.ndarray]:
    """Our joints' ranges (rad, README table / config/model.yaml)."""
    ranges = load_description().ranges
    lo = np.array([ranges[n][0] for n in JOINT_NAMES], float)
    hi = np.array([ranges[n][1] for n in JOINT_NAMES], float)
    return lo, hi


def find_spans(src: MyoArm, lo, hi, rng) -> list[list[int]]:
    q = rng.uniform(lo, hi, size=(40, 20))
    _, R = src.evaluate(q)
    return [list(np.nonzero(np.abs(R[:, i, :]).max(axis=0) > 1e-7)[0]) for i in range(R.shape[1])]


def check_signs(src: MyoArm, lo, hi) -> list[str]:
    mid = 0.5 * (lo + hi)
    _, R = src.evaluate(mid[None])
    bad = []
    for muscle, joint, sgn in SIGN_CHECKS:
        r = R[0, src.names.index(muscle), JOINT_NAMES.index(joint)]
        if np.sign(r) != sgn:
            bad.append(f"{muscle} about {joint}: {r * 1e3:+.2f} mm, expected sign {sgn:+d}")
    return bad
