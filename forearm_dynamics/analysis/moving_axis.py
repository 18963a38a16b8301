"""A second anatomical reference whose forearm rotation axis moves with the pro/sup angle.

MoBL-ARMS turns the radius about one fixed axis, so a fitted oblique hinge can partly
rediscover the reference's own axis. Measured forearm rotation is not a fixed hinge. This
reference keeps every MoBL body and the pro/sup coordinate, and makes the radioulnar
CustomJoint's SpatialTransform functions of that coordinate (LinearFunction, OpenSim):

- rotation 1: a tilt of the axis, about the ulna's anterior axis (orthogonalised to pro/sup)
  through the radial head, beta(q) = -TILT_TOTAL_DEG * q / range: the distal end of the
  rotation axis swings laterally in pronation and medially in supination, 7.14 deg over the
  whole range. Source: Weinberg AM, Pietsch IT, Helm MB, Hesselbach J, Tscherne H (2001)
  Die Pro- und Supination des Unterarms. Unfallchirurg 104(5):404-409 (MRI, 18 volunteers,
  36 forearms: the ulna's evasive motion of 7.14 deg during pro/supination; cadaver tests
  with the humerus fixed gave the same magnitude); direction: the ulna abducts in pronation
  (Ray RD, Johnson RJ, Jameson RM (1951) Rotation of the forearm: an experimental study of
  pronation and supination. J Bone Joint Surg Am 33(4):993-996). Here the swing is carried
  by the radius about the ulna (the ulna's own mass stays put): what moves is the axis the
  radius and hand turn about, which is what the simplified models approximate.
- rotation 2: about MoBL's pro/sup axis (as tilted by rotation 1), = q (as in MoBL);
- translation along the ulna's long axis, t(q) = TRANSLATION_TOTAL_MM * q / range: the radius
  moves proximally in pronation, 2.6 mm (SD 0.8) over the whole range. Source: 4-D CT of 10
  healthy volunteers, J Hand Surg Eur 2023;48(5):466-475 ("translations of the radius along
  the ulnar axis and the forearm rotation axis were 2.6 (SD 0.8) and 0.6 mm"); proximal in
  pronation: ulnar variance grows in pronation (Fu E et al. (2009) Elbow position affects
  distal radioulnar joint kinematics. J Hand Surg Am 34(7):1261-1268).

range = the model's pro/sup range (config/model.yaml, -80..80 deg): the measured totals are
spread linearly over it. The torques are OpenSim's inverse dynamics of that model (the
generalised force of the pro/sup coordinate includes the coupled motion's work).
"""

from __future__ import annotations

import numpy as np

from ..anthropometry import resolve_body_size
from ..builders import build_tree
from ..description import load_description
from ..opensim_engine import _orthonormal, _osim, _vec3, build_osim_model
from .placement import configured_overrides

TILT_TOTAL_DEG = 7.14
TRANSLATION_TOTAL_MM = 2.6
SOURCES = {
    "tilt": "Weinberg et al. 2001, Unfallchirurg 104(5):404-409 (7.14 deg ulnar evasive motion, MRI, "
            "n = 18); direction: Ray, Johnson & Jameson 1951, J Bone Joint Surg Am 33(4):993-996",
    "translation": "4-D CT, n = 10, J Hand Surg Eur 2023;48(5):466-475 (2.6 mm along the ulnar axis); "
                   "direction: Fu et al. 2009, J Hand Surg Am 34(7):1261-1268",
}


def coupling(desc=None, tilt_deg: float = TILT_TOTAL_DEG, translation_mm: float = TRANSLATION_TOTAL_MM
             ) -> dict:
    """Slopes of the coupled functions (per rad of pro/sup) and their axes (ulna frame)."""
    desc = desc or load_description()
    lo, hi = desc.ranges["pro_sup"]
    span = hi - lo
    a = np.asarray(desc.anatomical.radioulnar_axis, float)
    a = a / np.linalg.norm(a)
    x = np.array([1.0, 0.0, 0.0])
    tilt_axis = x - (x @ a) * a
    tilt_axis /= np.linalg.norm(tilt_axis)
    return {"axis": a, "tilt_axis": tilt_axis, "third_axis": np.cross(a, tilt_axis),
            "tilt_per_rad": -np.deg2rad(tilt_deg) / span,
            "translation_axis": np.array([0.0, 1.0, 0.0]),
            "translation_per_rad": 1e-3 * translation_mm / span}


def build_moving_axis_model(body_size=50, tilt_deg: float = TILT_TOTAL_DEG,
                            translation_mm: float = TRANSLATION_TOTAL_MM):
    """The anatomical OpenSim model with the coupled radioulnar joint (osim.Model)."""
    osim = _osim()
    desc = load_description()
    size = resolve_body_size(body_size)
    tree = build_tree("anatomical", desc, size)
    model = build_osim_model(tree)
    c = coupling(desc, tilt_deg, translation_mm)
    joint = next(j for j in tree.joints if j.name == "pro_sup")
    old = model.getJointSet().get("pro_sup")
    parent = model.getBodySet().get(joint.parent)
    child = model.getBodySet().get(joint.child)
    st = osim.SpatialTransform()
    names = osim.ArrayStr("pro_sup", 1)
    # OpenSim applies the three rotations as a body-fixed sequence: the tilt comes first, so it
    # turns about the ulna's (fixed) anterior axis and carries the pro/sup axis with it.
    for k, (ax, fn) in enumerate(((c["tilt_axis"], osim.LinearFunction(float(c["tilt_per_rad"]), 0.0)),
                                  (c["axis"], osim.LinearFunction(1.0, 0.0)),
                                  (c["third_axis"], osim.Constant(0.0)))):
        t = st.updTransformAxis(k)
        t.setAxis(_vec3(osim, ax))
        if not isinstance(fn, osim.Constant):
            t.setCoordinateNames(names)
        t.set_function(fn)
    trans = (c["translation_axis"], *_orthonormal(c["translation_axis"]))
    for k, ax in enumerate(trans):
        t = st.updTransformAxis(3 + k)
        t.setAxis(_vec3(osim, ax))
        if k == 0:
            t.setCoordinateNames(names)
            t.set_function(osim.LinearFunction(float(c["translation_per_rad"]), 0.0))
        else:
            t.set_function(osim.Constant(0.0))
    zero = osim.Vec3(0.0, 0.0, 0.0)
    # the wrist's parent is the radius body; the new joint replaces the old one in place
    model.updJointSet().remove(old)
    cj = osim.CustomJoint("pro_sup", parent, _vec3(osim, joint.origin), zero, child, zero, zero, st)
    model.addJoint(cj)
    coord = cj.upd_coordinates(0)
    coord.setRangeMin(float(joint.lower))
    coord.setRangeMax(float(joint.upper))
    coord.setDefaultClamped(False)
    coord.setDefaultLocked(False)
    model.finalizeConnections()
    return model, tree


class MovingAxisArm:
    """OpenSim inverse dynamics of the moving-axis reference, in JOINT_NAMES order."""

    def __init__(self, body_size=50, tilt_deg: float = TILT_TOTAL_DEG,
                 translation_mm: float = TRANSLATION_TOTAL_MM):
        from ..opensim_engine import OpenSimArm

        osim = _osim()
        self.model, self.tree = build_moving_axis_model(body_size, tilt_deg, translation_mm)
        self.joint_names = self.tree.joint_names
        self.nv = len(self.joint_names)
        self.shoulder = None  # the humerus fixed, as OpenSimArm.inverse_dynamics reads it
        self._state = self.model.initSystem()
        self._solver = osim.InverseDynamicsSolver(self.model)
        self._to_vector = osim.Vector.createFromMat
        self.internal_order = OpenSimArm._internal_order(self)

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        from ..opensim_engine import OpenSimArm

        return OpenSimArm.inverse_dynamics(self, q, qd, qdd)

    def energy(self, q, qd) -> float:
        """Kinetic + potential energy (J) at one state (for the power-balance check)."""
        s = self._state
        order = self.internal_order
        vec = self._to_vector
        s.setQ(vec(np.ascontiguousarray(np.asarray(q, float)[order])))
        s.setU(vec(np.ascontiguousarray(np.asarray(qd, float)[order])))
        self.model.realizeVelocity(s)
        return float(self.model.calcKineticEnergy(s) + self.model.calcPotentialEnergy(s))


VERSION = 2  # 2: tilt before the pro/sup rotation (a fixed tilt axis)
RATE_HZ = 200.0
REFIT = ("solid_fitted_axis", "oblique")


def reference_torques(trials, body_size=50) -> np.ndarray:
    """(M, N, 20) filtered OpenSim torques of the moving-axis reference."""
    from ..filtering import lowpass

    arm = MovingAxisArm(body_size)
    raw = np.stack([arm.inverse_dynamics(q, qd, qdd) for q, qd, qdd in
                    zip(trials.split(trials.q), trials.split(trials.qd), trials.split(trials.qdd),
                        strict=True)])
    return lowpass(raw, trials.rate_hz, axis=1)


def moving_axis_comparison(overrides: dict, cache, fit_rate_hz: float = 100.0, tick=None) -> dict:
    """Every headline model (shipped placements) against the moving-axis reference, paired
    statistics of the PAIRS, and the fitted variants refitted to it (in-sample best)."""
    from .comparison import Trials
    from .errors import global_range, summarize
    from .placement import HEADLINE, VARIANTS, Scorer, fit, start_of
    from .review import PAIRS, PRO_SUP
    from .statistics import clusters_of, paired

    spec = {"what": "moving_axis", "version": VERSION, "overrides": overrides, "rate_hz": RATE_HZ,
            "tilt_deg": TILT_TOTAL_DEG, "translation_mm": TRANSLATION_TOTAL_MM}

    def compute():
        trials = Trials.sample(RATE_HZ)
        r = reference_torques(trials)
        sc = Scorer(r, trials, global_range(list(r)), 50)
        clusters = clusters_of(trials.movement_ids)
        per = {n: sc.errors(VARIANTS[n], **overrides.get(n, {})) for n in HEADLINE}
        out = {"rate_hz": RATE_HZ, "models": {}, "pairs": []}
        for n, e in per.items():
            out["models"][n] = {"prosup_nrmse": summarize(e.nrmse[:, PRO_SUP]),
                                "prosup_nrmse_global": summarize(e.nrmse_global[:, PRO_SUP]),
                                "elbow_rmse_mean": float(np.mean(e.rmse[:, 0]))}
        for a, b, why in PAIRS:
            out["pairs"].append({"a": a, "b": b, "why": why,
                                 **paired(per[a].nrmse[:, PRO_SUP], per[b].nrmse[:, PRO_SUP], clusters)})
        # refits: how far the shipped placements are from this reference's own optimum
        ft = Trials.sample(fit_rate_hz)
        rf = reference_torques(ft)
        fsc = Scorer(rf, ft, global_range(list(rf)), 50)
        out["refit"] = {}
        for n in REFIT:
            v = VARIANTS[n]
            base = overrides.get(n) or configured_overrides(n)
            f = fit(v, fsc, start=start_of(v, base), callback=tick)
            e = sc.errors(v, **f["overrides"])
            out["refit"][n] = {"overrides": f["overrides"], "evaluations": f["evaluations"],
                               "prosup_nrmse": summarize(e.nrmse[:, PRO_SUP])}
        return out

    out = cache.get_or_compute(spec, compute)
    return {**out, "tilt_total_deg": TILT_TOTAL_DEG, "translation_total_mm": TRANSLATION_TOTAL_MM,
            "sources": SOURCES}

