"""What check_bag measures in a recorded run: pipeline error, model error, delivery.

Pipeline error (is the node computing what its model says?): recorded effort vs the SAME
model's inverse dynamics at the exact analytic state of each recorded stamp,
movement.evaluate(stamp - t0). Not filtered: both series are sampled at the same stamps,
and a sample-level error (late or wrong acceleration estimate, a stale sample) is what a
controller downstream receives; a 6 Hz filter would hide it. NRMSE per DOF per movement
= RMSE / peak-to-peak of the exact torques of that DOF over the whole movement (also when
the bag holds only part of it); DOFs whose peak-to-peak is under config/analysis.yaml
ptp_floor_nm are left out and counted.

Model error (how far is the shipped model from the gold standard?): recorded effort,
linearly resampled to the reference's uniform grid (k / rate_hz from t0), vs the OpenSim
reference torques, both low-passed at 6 Hz as in the paper. NRMSE per DOF per movement
(paper normalisation) and, for the gate, per DOF group over the bag (see check.yaml).

Simulated sensor input (a marker with "sensor": trajectory_publisher's noise_deg,
publish_velocity, jitter_ms, drop_fraction, seed): the truth is still
movement.evaluate(stamp - t0), so the torques are scored against the NOISELESS truth and
the report says which input was noisy and how. The pipeline gate (pipeline_nrmse_max) is
for exact input (exact velocities: noise_deg 0, velocities published); with noise or
positions only it is reported, not gated. The state check allows the stated noise: a
position may be off the truth by state_max_abs_rad + 7 noise standard deviations.

Delivery: joint_states without a joint_torques of the same header stamp are lost (those
received in the bag's last tail_grace_s are left out: their answers may have arrived after
the recorder stopped); the one-way latency is the joint_torques' log (receive) time minus
that stamp. Latency depends on the machine as much as on the code, so it is reported with
its target and the machine's load average (during the run, from the torque node's
/diagnostics when the bag has them, and at analysis time) and gates the verdict only when a
maximum is asked for (latency_p99_ms_max, or check_bag --max-latency-p99-ms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..analysis.errors import rmse
from ..codec.jointstate import JointSeries
from ..description import DOF_GROUPS
from ..filtering import analysis_config, lowpass
from ..model_config import ModelChoice
from ..movements import get_movement
from ..reference import ReferenceTorques
from .delivery import Delivery, MachineLoad, delivery, overflow_note
from .recording import Marker, Recording
from .thresholds import Thresholds


@dataclass
class MovementResult:
    index: int  # order in the bag
    id: int
    name: str
    elbow: str
    t0_ns: int
    window_ns: int  # up to the next marker, at most duration + LATE_MAX_NS
    samples: int
    expected: int  # announced by the marker, else duration x the stream's median stamp rate
    pipeline_nrmse: np.ndarray  # (J,) NaN where left out
    pipeline_left_out: int
    model_nrmse: np.ndarray | None = None  # (J,) per-movement normalisation (paper)
    model_note: str = ""
    state_error: float = float("nan")  # max |joint_states position - analytic q|, rad
    state_dof: str = ""
    shortfall: str = ""  # why samples < expected ("" when the movement is complete)
    #: joint_states the marker announced that are missing from the bag between the
    #: movement's first and last recorded ones, its whole window recorded (_holes): lost
    #: between a running publisher and the bag (DDS, the recorder); 0 when the marker
    #: announces no count or a simulated sensor drops samples on purpose (drop_fraction)
    inputs_missing: int = 0
    announced: bool = False  # `expected` is the marker's own count (trajectory_publisher)
    sensor: dict | None = None  # the marker's simulated-sensor settings, if any
    state_noise_rms: float = float("nan")  # rms of joint_states position - analytic q, rad

    @property
    def noise_rad(self) -> float:
        return math.radians(float((self.sensor or {}).get("noise_deg", 0.0)))

    @property
    def exact_input(self) -> bool:
        """Exact positions and velocities: the pipeline gate applies."""
        s = self.sensor or {}
        return float(s.get("noise_deg", 0.0)) == 0.0 and bool(s.get("publish_velocity", True))

    def worst(self, values: np.ndarray | None, names: tuple[str, ...]) -> tuple[float, str]:
        if values is None or not np.isfinite(values).any():
            return float("nan"), ""
        j = int(np.nanargmax(values))
        return float(values[j]), names[j]


@dataclass
class CheckReport:
    model: ModelChoice
    joint_names: tuple[str, ...]
    movements: list[MovementResult]
    model_groups: dict[str, dict[str, float]]
    delivery: Delivery
    warnings: list[str]
    failures: list[str] = field(default_factory=list)
    load: MachineLoad = field(default_factory=MachineLoad)
    queue_depth: int | None = None  # the torque node's input queue (its config), if it says


def _window(torques: JointSeries, t0_ns: int, window_ns: int) -> np.ndarray:
    return (torques.stamp_ns >= t0_ns) & (torques.stamp_ns < t0_ns + window_ns)


def _movement_ptp(arm, mv, cache: dict[int, np.ndarray]) -> np.ndarray:
    """Peak-to-peak of the exact torques over the whole movement (1 kHz grid): the scale of
    the pipeline NRMSE, also for a movement the bag holds only part of (a cut recording)."""
    if mv.id not in cache:
        cache[mv.id] = np.ptp(arm.inverse_dynamics(*mv.evaluate(mv.sample_times(1000.0))), axis=0)
    return cache[mv.id]


#: How far past its duration a movement's samples may be stamped: the publisher catches up
#: at most 0.5 s of late samples (trajectory_publisher.MAX_BURST at 1 kHz) and skips the rest.
LATE_MAX_NS = 500_000_000


def _pipeline(arm, marker: Marker, next_t0: int | None, torques: JointSeries, floor: float,
              index: int, ptp_cache: dict[int, np.ndarray] | None = None) -> MovementResult:
    """Samples t0 <= stamp < next marker belong to this movement, up to LATE_MAX_NS past its
    duration. Not cut at t0 + duration: the publisher stamps each sample when it sends it, so
    after a late timer tick (a loaded machine) its catch-up samples carry later stamps and a
    movement spans a little more than its duration; they are still this movement's,
    evaluated at stamp - t0 (the state check verifies that). The bound keeps a restarted
    publisher's samples out of the old movement if the new marker was not recorded."""
    mv = get_movement(marker.id)
    window = round(mv.duration * 1e9) + LATE_MAX_NS
    if next_t0 is not None:  # back-to-back movements: a sample belongs to one only
        window = min(window, next_t0 - marker.t0_ns)
    sel = _window(torques, marker.t0_ns, window)
    if marker.samples is not None:
        expected = marker.samples
    else:
        steps = np.diff(np.sort(torques.stamp_ns[sel]))
        steps = steps[steps > 0]
        expected = int(mv.duration * 1e9 / np.median(steps)) if len(steps) else 0
    nv = len(arm.joint_names)
    res = MovementResult(index, mv.id, marker.name or mv.name, marker.elbow or mv.elbow, marker.t0_ns,
                         window, int(sel.sum()), expected, np.full(nv, np.nan), 0,
                         sensor=marker.sensor, announced=marker.samples is not None)
    if res.samples == 0:
        return res
    t = (torques.stamp_ns[sel] - marker.t0_ns) / 1e9
    exact = arm.inverse_dynamics(*mv.evaluate(t))
    err = rmse(torques.effort[sel], exact)
    ptp = _movement_ptp(arm, mv, {} if ptp_cache is None else ptp_cache)
    keep = ptp >= floor
    with np.errstate(divide="ignore", invalid="ignore"):
        # a NaN effort (missing joint) must fail, not vanish: report it as infinite error
        res.pipeline_nrmse = np.where(keep, np.where(np.isfinite(err), err / ptp, np.inf), np.nan)
    res.pipeline_left_out = int((~keep).sum())
    return res


def _shortfall(res: MovementResult, duration_s: float, states: JointSeries | None,
               torques: JointSeries, end_ns: int) -> str:
    """Why a movement has fewer joint_torques than expected ("" if it has them all).

    Answers missing (joint_states without joint_torques) and inputs missing (fewer
    joint_states than expected: the recording ends inside the movement, the next marker
    came before the movement's end, or the publisher sent fewer) are told apart.
    """
    if res.samples >= res.expected:
        return ""
    why = []
    n_states = None
    if states is not None and len(states):
        sel = _window(states, res.t0_ns, res.window_ns)
        n_states = int(sel.sum())
        unanswered = int((~np.isin(states.stamp_ns[sel], torques.stamp_ns)).sum())
        if unanswered:
            why.append(f"{unanswered} of its {n_states} joint_states have no joint_torques")
    if n_states is None or n_states < res.expected:
        full_ns = round(duration_s * 1e9)
        if end_ns < res.t0_ns + min(res.window_ns, full_ns) - 10_000_000:
            why.append(f"the recording ends {(end_ns - res.t0_ns) / 1e9:.3f} s into it")
        elif res.window_ns < full_ns - 10_000_000:
            why.append(f"the next movement's marker comes {res.window_ns / 1e9:.3f} s after its "
                       f"start (it lasts {duration_s:.3f} s): its later samples count for the "
                       "next one")
        elif n_states is not None:
            why.append(f"only {n_states} joint_states were recorded in its window: the "
                       "publisher sent fewer, or the recorder missed them")
            if res.announced and not (res.sensor or {}).get("drop_fraction"):  # not dropped on purpose
                res.inputs_missing = _holes(states.stamp_ns[sel], res.t0_ns, res.expected,
                                            duration_s)
        else:
            why.append("no joint_states in the bag to tell whether inputs or answers are missing")
    return (f"{res.samples} of {res.expected} expected samples: " + "; ".join(why or [
        "joint_torques carry stamps outside the movement's window"]))


def _holes(stamps_ns: np.ndarray, t0_ns: int, expected: int, duration_s: float) -> int:
    """Announced samples missing between a movement's first and last recorded ones.

    Missing at either end is not counted: a publisher killed or stopped mid-movement sends no
    more (its tail), and a reader that matched a restarted publisher late misses its first
    samples (discovery): neither is a sample lost between a running publisher and the bag.
    The ends are estimated from the stamps on the movement's nominal grid (expected samples
    over duration_s); a late timer tick stamps samples later than the grid (the publisher
    stamps when it sends), which makes the ends look larger and the holes smaller, never
    the other way: a hole is counted only when the samples around it were recorded."""
    n = len(stamps_ns)
    if n < 2 or expected <= n:
        return 0
    period_ns = duration_s * 1e9 / expected
    first, last = int(stamps_ns.min()), int(stamps_ns.max())
    before = max(0, round((first - t0_ns) / period_ns))
    after = max(0, round((t0_ns + (expected - 1) * period_ns - last) / period_ns))
    return max(0, expected - n - before - after)


def _state_error(res: MovementResult, states: JointSeries, names: tuple[str, ...]) -> None:
    """Are the published positions the movement's analytic ones at their stamps?

    Separates a wrong publisher (bad samples in) from a wrong torque node (bad torques out).
    """
    sel = _window(states, res.t0_ns, res.window_ns)
    if not sel.any() or states.position is None:
        return
    q, _qd, _qdd = get_movement(res.id).evaluate((states.stamp_ns[sel] - res.t0_ns) / 1e9)
    diff = states.position[sel] - q
    with np.errstate(invalid="ignore"):
        res.state_noise_rms = float(np.sqrt(np.mean(diff**2)))
    err = np.abs(diff).max(axis=0)
    err = np.where(np.isnan(err), np.inf, err)  # a missing joint is as wrong as it gets
    j = int(np.argmax(err))
    res.state_error, res.state_dof = float(err[j]), names[j]


def _resampled(res: MovementResult, torques: JointSeries, ref: ReferenceTorques, pct: int,
               names: tuple[str, ...], min_coverage: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(recorded, reference) on the reference grid, both filtered; None (with a note) if not."""
    try:
        r = ref.torques(res.id, pct)
    except ValueError as exc:
        res.model_note = str(exc)
        return None
    cols = [ref.joint_names.index(n) for n in names]
    r = np.asarray(r, float)[:, cols]
    if res.samples < max(2.0, min_coverage * res.expected):
        res.model_note = f"only {res.samples} of {res.expected} samples"
        return None
    sel = _window(torques, res.t0_ns, res.window_ns)
    t = (torques.stamp_ns[sel] - res.t0_ns) / 1e9
    order = np.argsort(t)
    t, rec = t[order], torques.effort[sel][order]
    if not np.isfinite(rec).all():
        res.model_note = "recorded effort has NaN"
        return None
    grid = np.arange(r.shape[0]) / ref.rate_hz
    on_grid = np.column_stack([np.interp(grid, t, rec[:, j]) for j in range(rec.shape[1])])
    return lowpass(on_grid, ref.rate_hz), lowpass(r, ref.rate_hz)


def _library_scale(ref: ReferenceTorques, pct: int, cols: list[int]) -> np.ndarray:
    """Per DOF: the largest filtered peak-to-peak over every movement of the reference."""
    torques = np.asarray(ref.torques_all[ref.body_sizes.index(pct)], float)[..., cols]
    return np.ptp(lowpass(torques, ref.rate_hz, axis=1), axis=1).max(axis=0)


def _model_error(results: list[MovementResult], torques: JointSeries, ref: ReferenceTorques,
                 pct: int, names: tuple[str, ...], th: Thresholds) -> dict[str, dict[str, float]]:
    pairs = {res.index: p for res in results
             if (p := _resampled(res, torques, ref, pct, names, th.model_min_coverage)) is not None}
    if not pairs:
        return {}
    scale = _library_scale(ref, pct, [ref.joint_names.index(n) for n in names])
    lib_rows = []
    for res in results:
        if res.index not in pairs:
            continue
        test, gold = pairs[res.index]
        err = rmse(test, gold)
        ptp = np.ptp(gold, axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            # paper normalisation, only where the DOF really moves in this movement
            res.model_nrmse = np.where(ptp >= th.model_rel_floor * scale, err / ptp, np.nan)
            lib_rows.append(np.where(scale > 0, err / scale, np.nan))
    # Gate: normalised by each DOF's largest peak-to-peak over the whole reference library,
    # so the number does not depend on which movements the bag happens to hold.
    lib = np.array(lib_rows)
    groups = {}
    for group, dofs in DOF_GROUPS.items():
        idx = [names.index(d) for d in dofs if d in names]
        vals = lib[:, idx][np.isfinite(lib[:, idx])]
        groups[group] = {
            "n": int(vals.size),
            "median": float(np.median(vals)) if vals.size else float("nan"),
            "mean": float(vals.mean()) if vals.size else float("nan"),
            "max": float(vals.max()) if vals.size else float("nan"),
        }
    return groups


def analyse(rec: Recording, choice: ModelChoice, ref: ReferenceTorques | None, th: Thresholds,
            ref_problem: str | None = None, queue_depth: int | None = None) -> CheckReport:
    """All three measures and the threshold verdicts (report.failures)."""
    arm, names = choice.arm, choice.arm.joint_names
    warnings = list(rec.warnings) + list(choice.warnings)
    floor = float(analysis_config()["ptp_floor_nm"])
    torques = rec.joint_torques
    results = []
    ptp_cache: dict[int, np.ndarray] = {}
    series = [x for x in (rec.joint_states, torques) if x is not None and len(x)]
    last_stamp = max((int(x.stamp_ns.max()) for x in series), default=0)
    for k, marker in enumerate(rec.markers):
        next_t0 = rec.markers[k + 1].t0_ns if k + 1 < len(rec.markers) else None
        try:
            results.append(_pipeline(arm, marker, next_t0, torques, floor, k, ptp_cache))
        except ValueError as exc:
            warnings.append(f"movement marker {marker.id} ignored: {exc}")
    for line in sorted({sensor_note(r.sensor) for r in results if r.sensor and sensor_note(r.sensor)}):
        warnings.append(line)
    end_ns = max([last_stamp] + [int(x.log_ns.max()) for x in series])
    for res in results:
        if res.samples == 0:
            warnings.append(f"movement {res.id} at index {res.index}: no joint_torques in its window")
        if rec.joint_states is not None:
            _state_error(res, rec.joint_states, names)
        res.shortfall = _shortfall(res, get_movement(res.id).duration, rec.joint_states, torques,
                                   end_ns)
    groups: dict[str, dict[str, float]] = {}
    if ref is None:
        warnings.append(f"model error skipped: {ref_problem or 'no reference torques'}")
    elif choice.percentile is None:
        warnings.append("model error skipped: the reference has percentile body sizes only, "
                        f"the bag's model is {choice.arm.body_size.label}")
    else:
        # a movement whose model error is skipped says why in its own model_note
        groups = _model_error(results, torques, ref, choice.percentile, names, th)
    report = CheckReport(choice, names, results, groups,
                         delivery(rec.joint_states, torques, th.tail_grace_s), warnings,
                         load=MachineLoad.measure(rec.load_average), queue_depth=queue_depth)
    report.failures = verdicts(report, th)
    return report


def sensor_note(sensor: dict) -> str:
    """One line: how the input was degraded, and what the torques were scored against."""
    s = sensor
    parts = []
    if float(s.get("noise_deg", 0.0)):
        parts.append(f"Gaussian noise {float(s['noise_deg']):g} deg on positions")
    if not s.get("publish_velocity", True):
        parts.append("positions only (velocities not published)")
    if float(s.get("jitter_ms", 0.0)):
        parts.append(f"stamp jitter +-{float(s['jitter_ms']):g} ms")
    if float(s.get("drop_fraction", 0.0)):
        parts.append(f"{100 * float(s['drop_fraction']):g} % of samples dropped")
    if not parts:
        return ""
    gate = ("" if float(s.get("noise_deg", 0.0)) == 0.0 and s.get("publish_velocity", True)
            else "; the pipeline NRMSE gate applies to exact input only (reported, not gated)")
    return (f"input was a simulated sensor ({', '.join(parts)}, seed {s.get('seed')}): torques "
            f"scored against the noiseless analytic truth at the stamps{gate}")


def verdicts(report: CheckReport, th: Thresholds) -> list[str]:
    out = []
    names = report.joint_names
    for res in report.movements:
        allowed = th.state_max_abs_rad + 7.0 * res.noise_rad
        if res.state_error > allowed:
            out.append(f"joint_states position off the analytic trajectory by {res.state_error:.3g} "
                       f"rad in movement {res.id} ({res.name}, {res.elbow}) at DOF {res.state_dof}"
                       + (f" (stated noise {res.noise_rad:.3g} rad)" if res.noise_rad else "")
                       + ": the published samples are wrong (publisher side)")
        value, dof = res.worst(res.pipeline_nrmse, names)
        if value > th.pipeline_nrmse_max and res.exact_input:  # NaN passes, inf fails
            out.append(f"pipeline NRMSE {100 * value:.2f} % > {100 * th.pipeline_nrmse_max:g} % in "
                       f"movement {res.id} ({res.name}, {res.elbow}) at DOF {dof}")
    for group, s in report.model_groups.items():
        if s["median"] > th.model_group_median_nrmse_max:
            out.append(f"model NRMSE median {100 * s['median']:.1f} % > "
                       f"{100 * th.model_group_median_nrmse_max:g} % for DOF group {group}")
    d = report.delivery
    if d.lost > th.loss_max:
        where = ", ".join(stamp_text(s, report.movements) for s in d.lost_stamps_ns[:5])
        more = f" and {d.lost - 5} more" if d.lost > 5 else ""
        why = overflow_note(d, report.queue_depth, report.load)
        out.append(f"lost {d.lost} joint_states without joint_torques ({d.loss_pct:.3f} %; at most "
                   f"{th.loss_max} allowed): stamp {where}{more}" + (f"; {why}" if why else ""))
    missing = [r for r in report.movements if r.inputs_missing]
    n_missing = sum(r.inputs_missing for r in missing)
    if n_missing > th.loss_max:
        where = ", ".join(f"movement {r.id} at index {r.index} ({r.inputs_missing} of {r.expected})"
                          for r in missing[:5])
        out.append(f"lost {n_missing} joint_states before the bag: announced by their movement's "
                   f"marker, missing between samples that were recorded (at most "
                   f"{th.loss_max} allowed; DDS or the recorder dropped them, so no answer "
                   f"can be checked): {where}"
                   + (f" and {len(missing) - 5} more movements" if len(missing) > 5 else ""))
    p99 = d.latency_ms.get("p99", float("nan"))
    if th.latency_p99_ms_max is not None and p99 > th.latency_p99_ms_max:
        out.append(f"latency p99 {p99:.3f} ms > {th.latency_p99_ms_max:g} ms (asked-for maximum; "
                   f"{report.load.describe()})")
    return out


def stamp_text(stamp_ns: int, movements: list[MovementResult]) -> str:
    """A header stamp as sec.nanosec, and where it falls: movement id and time into it."""
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    text = f"{sec}.{nsec:09d}"
    for res in movements:
        if res.t0_ns <= stamp_ns < res.t0_ns + res.window_ns:
            return f"{text} (movement {res.id} at {(stamp_ns - res.t0_ns) / 1e9:.3f} s)"
    return text
