"""check_bag for any recording: a run without movement markers scored as one segment.

A subject's session (or a replay of real data) has no analytic trajectory to compare
with, so the reference is the offline practice of biomechanics: the recorded joint_states
positions filtered at 6 Hz zero-phase (filtering.py, config/analysis.yaml), velocity
and acceleration as derivatives of the filtered signal (estimation/offline.zero_phase),
inverse dynamics with the model the bag's config names. The recorded joint_torques are
compared with it at the same stamps:

- per DOF: RMSE (N·m) and NRMSE = RMSE / peak-to-peak of the reference (DOFs whose
  peak-to-peak is under analysis.yaml ptp_floor_nm are left out and counted);
- torque lag (ms, positive = recorded torques late) per DOF, by cross-correlation of the
  mean-removed series within +-max_lag, refined by a parabola through the peak; the
  median over the DOFs that move is the headline;
- delivery (loss, latency, rate), as with markers (check.delivery).

Physical checks that do not depend on that reference (issue 30: degrees read as radians
gave 1 490 N·m and PASSed, because the reference was computed from the same wrong angles):
- units: the measured angles against the joints' ranges (forearm_dynamics/ranges.py): far
  outside, or all within +-3 deg while moving, FAILs with "check units" (and no estimator
  advice: the numbers below are then meaningless);
- torque bound: |recorded torque| against the DOF group's bound (forearm_dynamics/bounds.py:
  the largest gravity + inertia torque at human speed, from the model);
- posture: the angles the node used (joint_torques position) against the measured ones,
  RMS in degrees per moving DOF, gated (check.yaml markerless_posture_rms_deg_max);
- still DOFs (measured angle peak-to-peak under check.yaml markerless_still_deg) are shown
  but left out of the NRMSE verdict.

The difference mixes the node's causal estimate (lag, noise) with the filter's smoothing,
so it is gated generously: the worst moving DOF's NRMSE above check.yaml
markerless_nrmse_max (0.5: an error of half the torque's own swing) fails, and the verdict
says what the number means and what to try (issue 16: a 100 Hz replay scored 3.0 and
PASSed). Verdicts (exit 1): that, lost samples beyond loss_max, torques that are not finite.
Stamps older than old_stamps_latency_s at arrival (a replayed old recording): the latency
is meaningless, said in a note naming bag_player's restamp.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..analysis.errors import rmse
from ..bounds import torque_bounds
from ..estimation.offline import zero_phase
from ..filtering import analysis_config, usable_cutoff
from ..model_config import ModelChoice
from ..ranges import check_recording
from .delivery import Delivery, MachineLoad, delivery, old_stamps_note, overflow_note
from .recording import Recording
from .thresholds import Thresholds

MAX_LAG_S = 0.2


@dataclass
class ScoreReport:
    model: ModelChoice
    joint_names: tuple[str, ...]
    samples: int  # joint_torques matched to a joint_states stamp
    duration_s: float
    cutoff_hz: float
    rmse: np.ndarray  # (J,) N·m
    nrmse: np.ndarray  # (J,) NaN where left out
    left_out: int
    lag_ms: np.ndarray  # (J,) NaN where left out
    lag_median_ms: float
    delivery: Delivery
    warnings: list[str]
    failures: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # qualify the numbers (old stamps)
    gate: float = float("nan")  # markerless_nrmse_max applied
    # what was compared, for the HTML report's plot: common stamps, recorded, reference
    compared: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    units: str | None = None  # the angles' range check refused them (one line: check units)
    still: np.ndarray | None = None  # (J,) bool: the measured angle does not move
    posture_rms_deg: np.ndarray | None = None  # (J,) node's angles vs measured, NaN if still
    peak_torque: np.ndarray | None = None  # (J,) N·m, largest |recorded torque|
    bound: np.ndarray | None = None  # (J,) N·m, the DOF group's human-speed bound
    bound_text: str = ""
    queue_depth: int | None = None  # the torque node's input queue (its config), if it says
    load: MachineLoad = field(default_factory=MachineLoad)


def lag_by_xcorr(rec: np.ndarray, ref: np.ndarray, dt: float, max_lag_s: float = MAX_LAG_S) -> float:
    """Delay (s) of `rec` behind `ref` (uniformly sampled at dt): argmax of their
    cross-correlation within +-max_lag, refined by a parabola; NaN if flat."""
    a, b = rec - rec.mean(), ref - ref.mean()
    if not (np.any(a) and np.any(b)):
        return float("nan")
    n = len(a)
    m = min(int(max_lag_s / dt), n - 2)
    if m < 1:
        return float("nan")
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    c = np.fft.irfft(np.fft.rfft(a, nfft) * np.conj(np.fft.rfft(b, nfft)), nfft)
    c = np.concatenate([c[-m:], c[:m + 1]])  # lags -m..m: c[k] = sum a[i+k] b[i]
    k = int(np.argmax(c))
    frac = 0.0
    if 0 < k < len(c) - 1:
        y0, y1, y2 = c[k - 1], c[k], c[k + 1]
        den = y0 - 2 * y1 + y2
        frac = 0.5 * (y0 - y2) / den if den != 0 else 0.0
    return (k - m + frac) * dt


def analyse_markerless(rec: Recording, choice: ModelChoice, th: Thresholds,
                       cutoff_hz: float | None = None,
                       queue_depth: int | None = None) -> ScoreReport:
    arm, names = choice.arm, choice.arm.joint_names
    states, torques = rec.joint_states, rec.joint_torques
    warnings = list(rec.warnings) + list(choice.warnings)
    cutoff = float(cutoff_hz if cutoff_hz is not None else analysis_config()["filter"]["cutoff_hz"])
    floor = float(analysis_config()["ptp_floor_nm"])
    nan = np.full(len(names), np.nan)
    d = delivery(states, torques, th.tail_grace_s)
    report = ScoreReport(choice, names, 0, 0.0, cutoff, nan, nan, 0, nan, float("nan"), d, warnings,
                         gate=th.markerless_nrmse_max, queue_depth=queue_depth,
                         load=MachineLoad.measure(rec.load_average))
    # reference at the joint_states stamps (ordered, unique, complete positions)
    order = np.argsort(states.stamp_ns, kind="stable")
    s_t, s_q = states.stamp_ns[order], states.position[order]
    keep = np.isfinite(s_q).all(axis=1) & np.concatenate([[True], np.diff(s_t) > 0])
    if (~keep).any():
        warnings.append(f"{int((~keep).sum())} joint_states without every joint's position "
                        "(or with a repeated stamp) left out of the reference")
    s_t, s_q = s_t[keep], s_q[keep]
    units = check_recording(s_q, names, source=f"{states.topic} positions")
    report.units = units.refusal
    warnings += units.warnings
    if len(s_q):
        report.still = np.degrees(np.ptp(s_q, axis=0)) < th.markerless_still_deg
    bounds = torque_bounds(arm)
    report.bound = np.array([bounds.of(n) for n in names])
    report.bound_text = bounds.assumption
    if torques is not None and len(torques) and torques.effort is not None:
        with np.errstate(invalid="ignore"):
            report.peak_torque = np.nanmax(np.abs(torques.effort), axis=0)
    if len(s_t) < 10:
        warnings.append(f"only {len(s_t)} usable joint_states: no reference computed")
        report.failures = _verdicts(report, th)
        return report
    step = float(np.median(np.diff(s_t)))
    gap = max(int(10 * step), 100_000_000)
    # a cutoff this bag's rate can use (a 10 Hz bag: not the practice's 6 Hz), said when changed
    cutoff, note = usable_cutoff(1e9 / step, cutoff_hz)
    report.cutoff_hz = cutoff
    if note is not None:
        warnings.append(note)
    q, qd, qdd = zero_phase(s_t, s_q, cutoff, gap)
    ref = arm.inverse_dynamics_batch(q, qd, qdd, check_ranges="off")  # units: judged above
    t_u, it = np.unique(torques.stamp_ns, return_index=True)
    common, ia, ib = np.intersect1d(s_t, t_u, assume_unique=True, return_indices=True)
    report.samples = len(common)
    if len(common) < 10:
        warnings.append(f"only {len(common)} joint_torques answer a joint_states stamp: nothing to compare")
        report.failures = _verdicts(report, th)
        return report
    r, x = ref[ia], torques.effort[it[ib]]
    used = torques.position[it[ib]]
    with np.errstate(invalid="ignore"):
        rms = np.degrees(np.sqrt(np.nanmean((used - s_q[ia]) ** 2, axis=0)))
    report.posture_rms_deg = np.where(report.still, np.nan, rms)
    report.compared = (common, x, r)
    report.duration_s = (common[-1] - common[0]) / 1e9
    err = rmse(x, r)
    ptp = np.ptp(r, axis=0)
    moving = ptp >= floor
    report.rmse = np.where(np.isfinite(err), err, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        report.nrmse = np.where(moving, report.rmse / ptp, np.nan)
    report.left_out = int((~moving).sum())
    dt = float(np.median(np.diff(common))) / 1e9
    grid = common[0] + np.round(np.arange(0, common[-1] - common[0] + 1, dt * 1e9)).astype(np.int64)
    lags = np.full(len(names), np.nan)
    finite = np.isfinite(x).all(axis=1)
    still = report.still if report.still is not None else np.zeros(len(names), bool)
    for j in np.flatnonzero(moving & ~still):  # a held joint's lag says nothing of it
        xs = np.interp(grid, common[finite], x[finite, j])
        rs = np.interp(grid, common, r[:, j])
        lags[j] = lag_by_xcorr(xs, rs, dt) * 1e3
    report.lag_ms = lags
    if np.isfinite(lags).any():
        report.lag_median_ms = float(np.nanmedian(lags))
    report.failures = _verdicts(report, th)
    report.notes = notes(report, th)
    return report


def worst_nrmse(report: ScoreReport) -> tuple[float, str]:
    """(the largest NRMSE over the moving DOFs, its DOF); (nan, '') when none. A DOF
    moves when its torque swings (analysis.yaml ptp_floor_nm) AND its measured angle does
    (check.yaml markerless_still_deg): a held joint is never the verdict."""
    x = np.asarray(report.nrmse, float)
    if report.still is not None:
        x = np.where(report.still, np.nan, x)
    if not np.isfinite(x).any():
        return float("nan"), ""
    j = int(np.nanargmax(x))
    return float(x[j]), report.joint_names[j]


def advice() -> str:
    """What the practice-NRMSE means and what to try (one line)."""
    return ("it means the torques differ from the 6 Hz zero-phase practice on the same data by "
            "that fraction of the torque's own swing; try: the kalman estimator (the default; "
            "`estimator:=kalman`), a delay if the controller can wait (`estimator.delay_s:=0.05`: "
            "the smoothed estimate 50 ms back), the noise the node believed (~/config "
            "estimator.noise_rad_per_joint; a fixed `estimator.kalman_noise_deg` if it is wrong), "
            "the joints the sensor lacks (`missing_joints:=hold` with `hold_posture.<joint>`), "
            "and the model the config names (body size, side, payload)")


def notes(report: ScoreReport, th: Thresholds) -> list[str]:
    """Lines that qualify the numbers without failing (old stamps)."""
    note = old_stamps_note(report.delivery, th.old_stamps_latency_s)
    return [note] if note else []


def _verdicts(report: ScoreReport, th: Thresholds) -> list[str]:
    out = []
    if report.units:  # the angles are wrong: nothing below means anything, no estimator advice
        out.append(report.units)
    if report.peak_torque is not None and report.bound is not None:
        over = np.flatnonzero(report.peak_torque > th.torque_bound_factor * report.bound)
        if len(over):
            j = int(over[np.argmax(report.peak_torque[over] / report.bound[over])])
            out.append(f"{report.joint_names[j]} torque reaches {report.peak_torque[j]:.4g} N·m, above "
                       f"{th.torque_bound_factor:g} x its group's bound {report.bound[j]:.3g} N·m "
                       f"({len(over)} DOF(s); {report.bound_text}): "
                       + ("check units" if report.units else
                          "no human movement gives it: check units, or noise amplified by the "
                          "estimator (estimator:=kalman)"))
    if report.posture_rms_deg is not None and not report.units:
        p = np.asarray(report.posture_rms_deg, float)
        if np.isfinite(p).any() and np.nanmax(p) > th.markerless_posture_rms_deg_max:
            j = int(np.nanargmax(p))
            out.append(f"posture: the angles the node used differ from the measured ones by "
                       f"{p[j]:.2f} deg RMS on {report.joint_names[j]} > "
                       f"{th.markerless_posture_rms_deg_max:g} deg (check.yaml "
                       "markerless_posture_rms_deg_max): the estimate does not follow the arm")
    worst, dof = worst_nrmse(report)
    if not report.units and np.isfinite(worst) and worst > th.markerless_nrmse_max:
        out.append(f"NRMSE against the offline practice {100 * worst:.0f} % on {dof} > "
                   f"{100 * th.markerless_nrmse_max:g} % (check.yaml markerless_nrmse_max): "
                   + advice())
    d = report.delivery
    if d.lost > th.loss_max:
        why = overflow_note(d, report.queue_depth, report.load)
        out.append(f"lost {d.lost} joint_states without joint_torques ({d.loss_pct:.2f} %) "
                   f"> {th.loss_max}" + (f"; {why}" if why else ""))
    bad = [n for n, e in zip(report.joint_names, report.rmse, strict=True) if e == np.inf]
    if bad:
        out.append(f"joint_torques effort not finite (or missing) for {', '.join(bad[:4])}")
    return out


def _num(x: float, fmt: str) -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, fmt)


def format_score(report: ScoreReport, bag_info) -> list[str]:
    lat, d = report.delivery.latency_ms, report.delivery
    lines = [(f"{bag_info.path}: {bag_info.message_count} messages, no movement markers: one segment "
             f"of {report.duration_s:.2f} s ({report.samples} samples); model {report.model.describe()}"),
             *(f"warning: {w}" for w in report.warnings),
             (f"reference: joint_states positions low-passed at {report.cutoff_hz:g} Hz zero-phase, "
             "derivatives of the filtered signal, inverse dynamics"),
             (f"{'DOF':<22} {'RMSE N·m':>10} {'NRMSE %':>8} {'lag ms':>8} {'posture°':>9} "
             f"{'|τ| max':>9} {'bound':>7}")]
    nan = np.full(len(report.joint_names), np.nan)
    posture = nan if report.posture_rms_deg is None else report.posture_rms_deg
    peak = nan if report.peak_torque is None else report.peak_torque
    bound = nan if report.bound is None else report.bound
    for j, n in enumerate(report.joint_names):
        still = report.still is not None and report.still[j]
        lines.append(f"{n:<22} {_num(report.rmse[j], '.4f'):>10} {_num(100 * report.nrmse[j], '.2f'):>8} "
                     f"{_num(report.lag_ms[j], '.2f'):>8} {_num(posture[j], '.3f'):>9} "
                     f"{_num(peak[j], '.4g'):>9} {_num(bound[j], '.3g'):>7}" + ("  still" if still else ""))
    if report.still is not None:
        lines.append(f"still: measured angle peak-to-peak under the check.yaml markerless_still_deg "
                     f"({int(report.still.sum())} DOF(s)): shown, left out of the verdict; posture° = "
                     "RMS of the node's angles - the measured ones; bound: " + report.bound_text)
    lines.append(f"torque lag (median over {int(np.isfinite(report.lag_ms).sum())} moving DOFs): "
                 f"{_num(report.lag_median_ms, '.2f')} ms; {report.left_out} DOF(s) left out "
                 "(peak-to-peak under the floor)")
    lines.append(
        f"delivery: joint_states {d.joint_states} ({_num(d.rate_hz.get('joint_states', np.nan), '.1f')} Hz), "
        f"joint_torques {d.joint_torques} ({_num(d.rate_hz.get('joint_torques', np.nan), '.1f')} Hz); "
        f"lost {d.lost} of {d.considered} ({_num(d.loss_pct, '.3f')} %); latency p50 "
        f"{_num(lat.get('p50', np.nan), '.3f')} ms, p99 {_num(lat.get('p99', np.nan), '.3f')} ms")
    worst, dof = worst_nrmse(report)
    if np.isfinite(worst):
        lines.append(f"NRMSE % = RMSE / the reference's peak-to-peak; worst {100 * worst:.1f} % "
                     f"({dof}), gate {100 * report.gate:g} % (check.yaml markerless_nrmse_max)")
    lines += [f"note: {x}" for x in report.notes]
    lines += [f"FAIL: {f}" for f in report.failures]
    lines.append("PASS" if not report.failures else f"FAIL ({len(report.failures)} problem(s))")
    return lines


def score_dict(report: ScoreReport) -> dict:
    names = report.joint_names
    d = report.delivery

    def clean(v):
        return float(v) if np.isfinite(v) else None

    return {
        "mode": "markerless",
        "model": report.model.summary(),
        "samples": report.samples, "duration_s": report.duration_s, "cutoff_hz": report.cutoff_hz,
        "rmse_nm": {n: clean(v) for n, v in zip(names, report.rmse, strict=True)},
        "nrmse": {n: clean(v) for n, v in zip(names, report.nrmse, strict=True)},
        "lag_ms": {n: clean(v) for n, v in zip(names, report.lag_ms, strict=True)},
        "lag_median_ms": clean(report.lag_median_ms), "left_out": report.left_out,
        "delivery": {"joint_states": d.joint_states, "joint_torques": d.joint_torques,
                     "considered": d.considered, "lost": d.lost, "loss_pct": clean(d.loss_pct),
                     "latency_ms": d.latency_ms, "rate_hz": d.rate_hz,
                     "lost_runs": d.lost_runs,
                     "behind_after_loss_ms": clean(d.behind_after_loss_ms)},
        "warnings": report.warnings, "failures": report.failures, "notes": report.notes,
        "nrmse_gate": report.gate,
        "units": report.units,
        "still": None if report.still is None else [n for n, x in zip(names, report.still, strict=True) if x],
        "posture_rms_deg": None if report.posture_rms_deg is None else
        {n: clean(v) for n, v in zip(names, report.posture_rms_deg, strict=True)},
        "torque_peak_nm": None if report.peak_torque is None else
        {n: clean(v) for n, v in zip(names, report.peak_torque, strict=True)},
        "torque_bound_nm": None if report.bound is None else
        {n: clean(v) for n, v in zip(names, report.bound, strict=True)},
        "torque_bound_assumption": report.bound_text,
    }
