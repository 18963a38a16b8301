"""benchmarks/corpus/derive.py's joint angles from markers (issue 29), on a synthetic arm with
known angles: elbow flexion, pro/sup (ours: 0 = hand in the sagittal plane, pronation
positive), wrist flexion and ulnar deviation come back exactly, for the right arm and for
the mirrored left arm, through the static calibration and the clusters' rigid fits; a
cluster that loses a marker still fits; the held-out subjects are refused."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks" / "corpus"))

import derive  # noqa: E402

# landmarks in their segment's frame (x forward, y proximal, z lateral: ISB, right arm)
HUM = {"GTH": [0.0, 0.30, 0.0], "LEP": [0.0, 0.0, 0.03], "MEP": [0.0, 0.0, -0.03]}
FORE = {"SPR": [0.0, -0.25, 0.05], "SPU": [0.0, -0.25, 0.0]}
HAND_FB = [0.0, -0.08, 0.0]  # from the styloid midpoint
CLUSTER = np.array([[0.03, 0.02, 0.04], [-0.02, 0.05, 0.04], [0.01, -0.03, 0.05], [0.04, 0.0, -0.02]])


def rz(a):
    return Rotation.from_euler("z", a).as_matrix()


def arm_markers(alpha, gamma_isb, flex, dev, side="R"):
    """Markers (N, 3) of one pose sequence: humerus fixed, forearm Rz(alpha) Ry(gamma),
    hand in the forearm Rz(flex) Rx(dev); hand frame origin at the styloid midpoint."""
    n = len(alpha)
    rf = Rotation.from_euler("ZY", np.stack([alpha, gamma_isb], axis=1)).as_matrix()
    rh_rel = Rotation.from_euler("ZX", np.stack([flex, dev], axis=1)).as_matrix()
    rhand = rf @ rh_rel
    shoulder = np.array([0.0, 0.30, 0.0])
    m = {}
    for k, p in HUM.items():
        m[k] = np.tile(p, (n, 1))
    for i, p in enumerate(CLUSTER):
        m[f"UAR{i + 1}"] = np.tile(p + [0.0, 0.15, 0.0], (n, 1))
        m[f"LAR{i + 1}"] = np.einsum("nij,j->ni", rf, p + [0.0, -0.12, 0.0])
        m[f"SHO{i + 1}"] = np.tile(shoulder + p * 0.5, (n, 1))
    for k, p in FORE.items():
        m[k] = np.einsum("nij,j->ni", rf, p)
    wrist = np.einsum("nij,j->ni", rf, (np.array(FORE["SPR"]) + FORE["SPU"]) / 2)
    m["FB"] = wrist + np.einsum("nij,j->ni", rhand, HAND_FB)
    for i, p in enumerate(CLUSTER):
        m[f"HAN{i + 1}"] = wrist + np.einsum("nij,j->ni", rhand, p * 0.8 + [0.0, -0.04, 0.0])
    out = {f"{side}{k}": v for k, v in m.items()}
    # the other shoulder's cluster, medial (for the approximate thorax frame)
    for i, p in enumerate(CLUSTER):
        out[f"{'L' if side == 'R' else 'R'}SHO{i + 1}"] = np.tile([0.0, 0.30, -0.35] + p * 0.5, (n, 1))
    if side == "L":  # the left arm is the right arm's mirror image
        out = {k: v * [1.0, 1.0, -1.0] for k, v in out.items()}
    # lab frame: x lateral (right), y forward, z up, as the Vicon files
    lab = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return {k: v @ lab.T for k, v in out.items()}


@pytest.mark.parametrize("side", ["R", "L"])
def test_angles_from_markers_are_the_posed_ones(side) -> None:
    static = arm_markers(np.radians([10.0]), np.radians([90.0]), np.zeros(1), np.zeros(1), side)
    cal = derive.Subject(static, side)
    n = 50
    t = np.linspace(0, 1, n)
    alpha = np.radians(20 + 100 * t)
    gamma = np.radians(30 + 100 * t)  # ISB: 0 = full supination
    flex = np.radians(-30 + 50 * t)
    dev = np.radians(-10 + 25 * t)
    trial = arm_markers(alpha, gamma, flex, dev, side)
    trial[f"{side}UAR2"][5] = np.nan  # a marker lost: the three others still fit
    q, shoulder, run, total = cal.angles(trial)
    assert (run.start, run.stop, total) == (0, n, n)
    np.testing.assert_allclose(q[:, 0], alpha, atol=1e-9)
    np.testing.assert_allclose(q[:, 1], gamma - np.pi / 2, atol=1e-9)  # ours: pronation from neutral
    np.testing.assert_allclose(q[:, 2], flex, atol=1e-9)
    np.testing.assert_allclose(q[:, 3], dev, atol=1e-9)
    assert np.isfinite(shoulder).all()


def test_a_cluster_of_two_markers_ends_the_usable_run() -> None:
    static = arm_markers(np.radians([10.0]), np.radians([90.0]), np.zeros(1), np.zeros(1))
    cal = derive.Subject(static, "R")
    trial = arm_markers(np.radians(np.linspace(20, 60, 30)), np.full(30, 1.0), np.zeros(30), np.zeros(30))
    trial["RLAR1"][20:] = np.nan
    trial["RLAR2"][20:] = np.nan
    _q, _sh, run, total = cal.angles(trial)
    assert (run.start, run.stop, total) == (0, 20, 30)


def test_the_reviewers_subjects_are_refused(tmp_path) -> None:
    with pytest.raises(SystemExit, match="held out by the reviewer"):
        derive.derive_ue_adl(tmp_path, ["ADL005"], "D", "R", "1")
