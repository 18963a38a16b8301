"""A user's own OpenSim model -> our muscle model file (muscles/source_osim.py), checked
against OpenSim itself.

The model is built here, in a temporary folder, with the OpenSim API: our skeleton
(opensim_engine.build_osim_model) plus four DeGrooteFregly2016Muscles with real path points
(one across the elbow, one across pro/sup, one across elbow and pro/sup, one across both
wrist DOF). No MoBL-ARMS, no network. The fitted file is read by the node's loader
(load_muscle_model) and its moment arms compared with OpenSim's own
Muscle.computeMomentArm on postures the fit never saw, the test mapping the angles itself.
"""

from __future__ import annotations

import json
import math
import re
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from forearm_dynamics import build_model
from forearm_dynamics.coordinate_map import CoordinateMap
from forearm_dynamics.description import JOINT_NAMES
from forearm_dynamics.errors import MotionError, UsageError
from forearm_dynamics.muscles import MuscleModelError, load_muscle_model
from forearm_dynamics.muscles.fit import FitSizes, joint_box

pytestmark = pytest.mark.unit

osim = pytest.importorskip("opensim")  # the optional [reference] extra; only a guard

from forearm_dynamics.muscles import source_osim  # noqa: E402 (after the guard)
from forearm_dynamics.opensim_engine import build_osim_model  # noqa: E402

BOUND_MM = 1.0  # the target: RMS per (muscle, joint) pair against the source
SIZES = FitSizes(n_fit=500, n_test=150, n_edge_base=8, jump_bases=1, n_envelope=100)
#: name -> (max isometric force N, optimal fibre m, tendon slack m, pennation rad, vmax L0/s,
#:          path points (body, (x, y, z) in its frame))
MUSCLES = {
    "ELB": (612.5, 0.1032, 0.1517, 0.0873, 12.0,
            [("humerus", (0.025, -0.17, 0.0)), ("forearm_proximal", (0.02, -0.06, 0.005))]),
    "PRO": (310.0, 0.0491, 0.0334, 0.1745, 0.0,  # vmax 0: replaced by 10, listed
            [("forearm_proximal", (-0.015, -0.05, -0.02)), ("forearm_distal", (0.025, -0.03, 0.02))]),
    "BIC": (580.25, 0.1161, 0.2723, 0.0, 8.5,
            [("humerus", (0.03, -0.05, 0.01)), ("forearm_proximal", (0.025, -0.03, 0.0)),
             ("forearm_distal", (0.02, -0.01, 0.025))]),
    "WRI": (241.0, 0.0627, 0.2459, 0.0524, 10.0,
            [("forearm_distal", (0.03, -0.04, 0.015)), ("carpus", (0.012, -0.035, -0.01))]),
}
#: the user's map: every arm coordinate named (strict), deviation with the opposite sign,
#: pro/sup with an offset (ours = theirs - 90°, as Rajagopal's pro_sup_r)
USER_MAP = """coordinates:
  elbow_flexion: {joint: elbow_flexion, sign: 1, offset_deg: 0}
  pro_sup: {joint: pro_sup, sign: 1, offset_deg: -90}
  wrist_flexion: {joint: wrist_flexion, sign: 1, offset_deg: 0}
  wrist_deviation: {joint: wrist_deviation, sign: -1, offset_deg: 0}
"""


def write_model(folder: Path, edit=None, muscles: dict = MUSCLES, ranges_deg: dict | None = None
                ) -> Path:
    """Our skeleton with `muscles` as an .osim file; `edit(muscle)` may change one first.
    pro_sup's coordinate range is ±180° (the user's map shifts it by 90°), the others ours,
    or `ranges_deg` {coordinate: (lo, hi)}."""
    model = build_osim_model(build_model("segmented", 50).tree)
    for name, (lo, hi) in {"pro_sup": (-180.0, 180.0), **(ranges_deg or {})}.items():
        c = model.getCoordinateSet().get(name)
        c.setRangeMin(math.radians(lo))
        c.setRangeMax(math.radians(hi))
    bodies = model.getBodySet()
    for name, (f0, l0, lts, alpha, vmax, points) in muscles.items():
        m = osim.DeGrooteFregly2016Muscle()
        m.setName(name)
        m.set_max_isometric_force(f0)
        m.set_optimal_fiber_length(l0)
        m.set_tendon_slack_length(lts)
        m.set_pennation_angle_at_optimal(alpha)
        m.set_max_contraction_velocity(vmax)
        for k, (body, xyz) in enumerate(points):
            m.addNewPathPoint(f"{name}_p{k}", bodies.get(body), osim.Vec3(*xyz))
        if edit is not None:
            edit(m)
        model.addForce(m)
    model.finalizeConnections()
    path = folder / "arm.osim"
    model.printToXML(str(path))
    return path


def opensim_moment_arms(path: Path, q: np.ndarray, cmap: dict) -> np.ndarray:
    """OpenSim's own computeMomentArm at our postures q (N, 20), mapped here (not by the
    module under test): theirs = sign * (ours - offset); r_ours = sign * r_theirs."""
    model = osim.Model(str(path))
    s = model.initSystem()
    cs, ms = model.getCoordinateSet(), model.getMuscles()
    out = np.zeros((len(q), len(MUSCLES), 20))
    for k, qk in enumerate(q):
        for theirs, (joint, sign, off) in cmap.items():
            cs.get(theirs).setValue(s, sign * (qk[JOINT_NAMES.index(joint)] - off), False)
        model.realizePosition(s)
        for i, name in enumerate(MUSCLES):
            for theirs, (joint, sign, _) in cmap.items():
                out[k, i, JOINT_NAMES.index(joint)] = \
                    sign * ms.get(name).computeMomentArm(s, cs.get(theirs))
    return out


@cache
def fitted(tmp: Path) -> tuple[Path, Path, dict]:
    osim_file = write_model(tmp)
    map_file = tmp / "map.yaml"
    map_file.write_text(USER_MAP, encoding="utf-8")
    out = tmp / "muscles.json"
    doc, _ = source_osim.build_osim(osim_file, out, cmap=CoordinateMap.load(map_file),
                                    sizes=SIZES, progress=None)
    return osim_file, out, doc


@pytest.fixture(scope="module")
def fit(tmp_path_factory):
    return fitted(tmp_path_factory.mktemp("osim"))


@pytest.mark.slow  # the fit: 3 s (load 3.5) to 17 s (load 8) on 2 cores
def test_surrogate_matches_opensim_compute_moment_arm_on_unseen_postures(fit):
    osim_file, out, _ = fit
    mm = load_muscle_model(out)
    assert mm.names == tuple(MUSCLES)
    assert {n: set(s) for n, s in zip(mm.names, mm.spans)} == {
        "ELB": {"elbow_flexion"}, "PRO": {"pro_sup"}, "BIC": {"elbow_flexion", "pro_sup"},
        "WRI": {"wrist_flexion", "wrist_deviation"}}
    lo, hi = joint_box()
    q = np.random.default_rng(2026).uniform(lo, hi, size=(120, 20))  # not the fit's seed
    cmap = {"elbow_flexion": ("elbow_flexion", 1, 0.0), "pro_sup": ("pro_sup", 1, -math.pi / 2),
            "wrist_flexion": ("wrist_flexion", 1, 0.0),
            "wrist_deviation": ("wrist_deviation", -1, 0.0)}
    R_src = opensim_moment_arms(osim_file, q, cmap)
    R_fit = mm.moment_arms(q)
    worst = {}
    for i, (name, span) in enumerate(zip(mm.names, mm.spans)):
        for joint in JOINT_NAMES:
            j = JOINT_NAMES.index(joint)
            rms = float(np.sqrt(np.mean((R_fit[:, i, j] - R_src[:, i, j]) ** 2))) * 1e3
            if joint in span:
                assert np.abs(R_src[:, i, j]).max() > 2e-3, (name, joint)  # a real moment arm
                worst[(name, joint)] = rms
            else:
                assert np.abs(R_src[:, i, j]).max() < 1e-9 and not R_fit[:, i, j].any()
    assert max(worst.values()) <= BOUND_MM, worst
    # the sign: deviation's map is -1, so the file's moment arm is minus OpenSim's
    wri = mm.names.index("WRI")
    dev = JOINT_NAMES.index("wrist_deviation")
    assert np.corrcoef(R_fit[:, wri, dev], R_src[:, wri, dev])[0, 1] > 0.99


@pytest.mark.slow  # the fit: 3 s (load 3.5) to 17 s (load 8) on 2 cores
def test_parameters_carried_exactly_and_provenance(fit):
    osim_file, out, doc = fit
    for m in doc["muscles"]:
        f0, l0, lts, alpha, vmax, _ = MUSCLES[m["name"]]
        assert (m["max_isometric_force"], m["optimal_fiber_length"],
                m["tendon_slack_length"], m["pennation_at_optimal"]) == (f0, l0, lts, alpha)
        assert m["max_contraction_velocity"] == (vmax if vmax > 0 else source_osim.DEFAULT_VMAX)
    src = doc["source"]
    assert src["vmax_replaced"] == ["PRO"]
    assert src["sha256"] == source_osim.sha256(osim_file) and len(src["sha256"]) == 64
    assert src["licence"] == "as stated by the user's file"
    assert src["url"] == str(osim_file)
    assert src["mapping"]["wrist_deviation"] == {"source_joint": "wrist_deviation", "sign": -1.0,
                                                 "offset_deg": 0.0}
    assert src["mapping"]["pro_sup"]["offset_deg"] == -90.0
    assert json.loads(out.read_text(encoding="utf-8"))["format"] == "forearm_dynamics.muscles/1"


def test_muscle_crossing_none_of_our_joints_is_dropped_and_listed(tmp_path):
    hum = {"HUM": (100.0, 0.1, 0.1, 0.0, 10.0, [("humerus", (0.02, -0.05, 0.0)),
                                                 ("humerus", (0.02, -0.2, 0.01))])}
    src = source_osim.OsimSource(write_model(tmp_path, muscles={**hum, **MUSCLES}),
                                 progress=None)
    assert src.dropped == ["HUM"] and src.names == list(MUSCLES)
    assert src.source()["dropped_muscles"] == ["HUM"]


def _refusal(tmp_path, capsys, *argv) -> str:
    code = source_osim.main([*map(str, argv), "-o", str(tmp_path / "out.json")])
    err = capsys.readouterr().err.strip()
    assert code in (1, 2) and "\n" not in err and "Traceback" not in err, (code, err)
    assert not (tmp_path / "out.json").exists()
    return err


def test_missing_or_zero_optimal_fibre_length_refused_naming_the_muscle(tmp_path, capsys):
    path = write_model(tmp_path)
    text = path.read_text(encoding="utf-8")
    wri = text.index('<DeGrooteFregly2016Muscle name="WRI">')
    cut = re.sub(r"<optimal_fiber_length>[^<]*</optimal_fiber_length>", "", text[wri:], count=1)
    path.write_text(text[:wri] + cut, encoding="utf-8")
    err = _refusal(tmp_path, capsys, path)
    assert "'WRI'" in err and "optimal_fiber_length" in err and "missing" in err, err
    with pytest.raises(MuscleModelError, match=r"'PRO'.*optimal_fiber_length.* = 0\.0"):
        source_osim.OsimSource(write_model(tmp_path, edit=lambda m: m.getName() == "PRO"
                                           and m.set_optimal_fiber_length(0.0)), progress=None)


def test_unknown_coordinate_in_the_map_reported_in_one_line(tmp_path, capsys):
    path = write_model(tmp_path)
    bad = tmp_path / "typo.yaml"
    bad.write_text(USER_MAP.replace("wrist_flexion: {", "wrist_flexon: {"), encoding="utf-8")
    err = _refusal(tmp_path, capsys, path, "--map", bad)
    assert "wrist_flexon" in err and "name no coordinate" in err, err
    unknown_joint = tmp_path / "joint.yaml"
    unknown_joint.write_text(USER_MAP.replace("{joint: wrist_flexion", "{joint: wrist_flex"),
                             encoding="utf-8")
    err = _refusal(tmp_path, capsys, path, "--map", unknown_joint)
    assert "wrist_flex'" in err and "unknown joint" in err, err
    with pytest.raises(MotionError):
        source_osim.OsimSource(path, cmap=CoordinateMap.load(bad), progress=None)


def test_without_opensim_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    import builtins

    real = builtins.__import__

    def no_opensim(name, *a, **k):
        if name == "opensim":
            raise ImportError("No module named 'opensim'")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_opensim)
    code = source_osim.main([str(tmp_path / "x.osim"), "-o", str(tmp_path / "o.json")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "pip install -e '.[reference]'" in err, err


def test_exclude_and_anatomical_action_report(tmp_path):
    """--exclude leaves a muscle out (listed); a muscle named as one of fit.SIGN_CHECKS (PT
    pronates) is checked through the map: right with the file's sign, reported wrong with
    the opposite one (a map whose pro_sup sign is flipped)."""
    pt = {"PT": MUSCLES["PRO"]}  # proximal ulna -> distal radius: OpenSim's sign decides
    path = write_model(tmp_path, muscles={**pt, **MUSCLES})
    src = source_osim.OsimSource(path, progress=None, exclude=("ELB",))
    assert "ELB" not in src.names and src.source()["excluded_muscles"] == ["ELB"]
    assert src.source()["fit_box_deg"]["wrist_flexion"] == [-70.0, 80.0]  # ours: not cut
    good, bad = source_osim.action_checks(src)
    flipped = _write(tmp_path / "flip.yaml", USER_MAP.replace(
        "pro_sup: {joint: pro_sup, sign: 1, offset_deg: -90}",
        "pro_sup: {joint: pro_sup, sign: -1, offset_deg: 0}"))
    good2, bad2 = source_osim.action_checks(
        source_osim.OsimSource(path, cmap=CoordinateMap.load(flipped), progress=None))
    assert len(good) + len(bad) == 1 and len(good2) + len(bad2) == 1
    assert (len(good), len(good2)) in ((1, 0), (0, 1))  # the sign flips the verdict
    with pytest.raises(UsageError, match="NOPE"):
        source_osim.OsimSource(path, progress=None, exclude=("NOPE",))


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_fit_box_is_cut_to_the_models_own_ranges(tmp_path):
    """Past its coordinates' ranges a model's geometry is untested: the fit stays inside
    (mapped through the sign: wrist_deviation -1 turns theirs [-10, 25] into ours [-25, 10])."""
    path = write_model(tmp_path, ranges_deg={"wrist_flexion": (-60.0, 60.0),
                                             "wrist_deviation": (-10.0, 25.0)})
    src = source_osim.OsimSource(path, cmap=CoordinateMap.load(
        _write(tmp_path / "m.yaml", USER_MAP)), progress=None)
    box = src.source()["fit_box_deg"]
    assert box["wrist_flexion"] == [-60.0, 60.0]
    assert box["wrist_deviation"] == [-20.0, 10.0]  # ours -20..30 cut by -25..10
    assert box["elbow_flexion"] == [0.0, 130.0] and box["pro_sup"] == [-80.0, 80.0]
