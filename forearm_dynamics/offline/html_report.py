"""check_bag --html: the report as one self-contained HTML file that opens without a network.

Plotly draws every figure (zoom, pan, hover, legend toggles); its offline JavaScript bundle
is embedded once in the file (plotly.offline.get_plotlyjs), so the file needs nothing else:
no CDN, no server, no second file. Contents, top to bottom: the verdict (PASS / FAIL and
every failure sentence), warnings, model and machine load, the per-movement error table,
model error per DOF group, delivery (counts, loss, latency percentiles), histograms of the
one-way latency and of the joint_torques inter-arrival times, then one figure per movement:
the recorded torques against the truth (the same model's inverse dynamics at the exact
state of each stamp: the pipeline error) and against the reference (the OpenSim anatomical
model, 6 Hz low-passed as in the paper: the model error), one row per DOF group.

Traces are thinned to at most MAX_POINTS points per movement (evenly spaced samples, the
first and last kept) and stored as float32, so a 65-movement bag stays a few MB; the
figures are for looking, the numbers in the tables are computed from every sample.
"""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np
import plotly.graph_objects as go
from plotly.io import to_html
from plotly.offline import get_plotlyjs
from plotly.subplots import make_subplots

from ..description import DOF_GROUPS
from ..filtering import lowpass
from ..movements import get_movement

MAX_POINTS = 250
#: Colours of the joints within a group (plotly's default qualitative sequence, then Dark24).
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf", "#2e91e5", "#e15f99")
CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222;max-width:1400px}
h1{font-size:1.4em} h2{font-size:1.15em;margin-top:1.6em}
.verdict{font-size:1.3em;font-weight:bold;padding:.4em .8em;display:inline-block;border-radius:4px}
.pass{background:#d4f4dd;color:#11602a} .fail{background:#fbd9d9;color:#8a1111}
table{border-collapse:collapse;font-size:.9em} td,th{border:1px solid #ccc;padding:2px 6px}
td.num{text-align:right;font-variant-numeric:tabular-nums} .note{color:#555;font-size:.9em}
"""


def _thin(n: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, MAX_POINTS)).round().astype(int)) if n else \
        np.zeros(0, int)


def _f32(x) -> np.ndarray:
    return np.asarray(x, np.float32)


def _num(x: float, fmt: str) -> str:
    return "–" if x is None or not math.isfinite(x) else format(x, fmt)


def _pct(x: float) -> str:
    return _num(100 * x if x is not None else x, ".2f")


def _table(header: list[str], rows: list[list[str]], numeric_from: int = 1) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f'<td class="num">{html.escape(c)}</td>' if i >= numeric_from else
                         f"<td>{html.escape(c)}</td>" for i, c in enumerate(r)) + "</tr>"
        for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def movement_figure(res, torques, arm, ref, percentile) -> go.Figure:
    """Recorded vs truth (and vs the reference, when there is one) for one movement."""
    names = arm.joint_names
    mv = get_movement(res.id)
    sel = (torques.stamp_ns >= res.t0_ns) & (torques.stamp_ns < res.t0_ns + res.window_ns)
    t_all = (torques.stamp_ns[sel] - res.t0_ns) / 1e9
    order = np.argsort(t_all)
    t, rec = t_all[order], torques.effort[sel][order]
    keep = _thin(len(t))
    t, rec = t[keep], rec[keep]
    truth = arm.inverse_dynamics(*mv.evaluate(t)) if len(t) else np.zeros((0, len(names)))
    gold = gold_t = None
    if ref is not None and percentile is not None and res.model_nrmse is not None:
        r = np.asarray(ref.torques(res.id, percentile), float)[:, [ref.joint_names.index(n)
                                                                   for n in names]]
        k = _thin(len(r))
        gold, gold_t = lowpass(r, ref.rate_hz)[k], (np.arange(len(r)) / ref.rate_hz)[k]
    series = [(t, rec, "recorded", None, 1.5), (t, truth, "truth", "dash", 1)]
    if gold is not None:
        series.append((gold_t, gold, "reference (OpenSim, 6 Hz)", "dot", 1))
    return _dof_group_figure(
        names, series, "time since the movement's first sample (s)",
        f"movement {res.id}: {res.name} (elbow {res.elbow}); solid recorded, dashed truth, "
        "dotted reference")


def _dof_group_figure(names, series, x_title: str, title: str) -> go.Figure:
    """One row per DOF group, one colour per DOF, each series (t, values (N, J), label, dash,
    width) drawn for every DOF in that colour: the movement and the segment pages alike."""
    groups = list(DOF_GROUPS.items())
    fig = make_subplots(rows=len(groups), cols=1, shared_xaxes=True, vertical_spacing=0.03,
                        subplot_titles=[f"{g} (N·m)" for g, _ in groups])
    for row, (_group, dofs) in enumerate(groups, start=1):
        for k, dof in enumerate(d for d in dofs if d in names):
            j, colour = names.index(dof), PALETTE[k % len(PALETTE)]
            for ts, values, label, dash, width in series:
                line = {"color": colour, "width": width} | ({"dash": dash} if dash else {})
                fig.add_trace(go.Scatter(x=_f32(ts), y=_f32(values[:, j]), name=f"{dof} {label}",
                                         legendgroup=dof, line=line), row=row, col=1)
    fig.update_xaxes(title_text=x_title, row=len(groups), col=1)
    fig.update_layout(height=230 * len(groups), margin={"l": 60, "r": 20, "t": 60, "b": 40},
                      title=title, legend={"font": {"size": 9}})
    return fig


def _histogram(values: np.ndarray, title: str, xlabel: str) -> go.Figure:
    fig = go.Figure(go.Histogram(x=_f32(values), nbinsx=80, marker={"color": "#1f77b4"}))
    fig.update_layout(title=title, height=320, xaxis_title=xlabel, yaxis_title="messages",
                      yaxis_type="log", margin={"l": 60, "r": 20, "t": 50, "b": 40})
    return fig


def _latency_ms(states, torques) -> np.ndarray:
    """joint_torques log time - stamp, for the torques answering a joint_states (ms)."""
    if states is None or torques is None or not len(torques):
        return np.zeros(0)
    answered = np.isin(torques.stamp_ns, states.stamp_ns)
    return (torques.log_ns[answered] - torques.stamp_ns[answered]) / 1e6


def _div(fig: go.Figure, div_id: str, cls: str) -> str:
    return (f'<div class="{cls}">'
            + to_html(fig, full_html=False, include_plotlyjs=False, div_id=div_id,
                      config={"displaylogo": False, "responsive": True})
            + "</div>")


def movement_rows(report) -> list[list[str]]:
    names = report.joint_names
    rows = []
    for r in report.movements:
        pv, pd = r.worst(r.pipeline_nrmse, names)
        mv, md = r.worst(r.model_nrmse, names)
        rows.append([str(r.id), r.name, r.elbow, f"{r.samples}/{r.expected}",
                     _num(r.state_error, ".1e"), _pct(pv), pd, _pct(mv), md,
                     r.shortfall or r.model_note or ""])
    return rows


def _head(bag_info, failures: list[str], warnings: list[str], code: int) -> list[str]:
    ok = not failures
    verdict = "PASS: the data are right" if ok else f"FAIL: {len(failures)} threshold(s) exceeded"
    parts = [f"<h1>check_bag: {html.escape(str(bag_info.path))}</h1>",
             (f'<p><span class="verdict {"pass" if ok else "fail"}" id="verdict">{verdict}'
              f"</span> exit code {code}</p>")]
    if failures:
        parts.append("<ul>" + "".join(f"<li>{html.escape(f)}</li>" for f in failures) + "</ul>")
    if warnings:
        parts.append('<ul class="note">' + "".join(f"<li>warning: {html.escape(w)}</li>"
                                                   for w in warnings) + "</ul>")
    return parts


def _delivery(d, rec, notes: list[str]) -> list[str]:
    lat = d.latency_ms or {}
    parts = ["<h2>Delivery</h2>", _table(["", "value"], [
        ["joint_states", str(d.joint_states)], ["joint_torques", str(d.joint_torques)],
        ["judged", str(d.considered)], ["lost", str(d.lost)], ["loss (%)", _num(d.loss_pct, ".3f")],
        ["latency p50 (ms)", _num(lat.get("p50", math.nan), ".3f")],
        ["latency p99 (ms)", _num(lat.get("p99", math.nan), ".3f")],
        ["latency max (ms)", _num(lat.get("max", math.nan), ".3f")],
        *[[f"rate {k} (Hz)", _num(v, ".1f")] for k, v in d.rate_hz.items()],
        *[[f"max gap {k} (ms)", _num(v, ".2f")] for k, v in d.max_gap_ms.items()]])]
    parts.append("".join(f"<p class='note'>{html.escape(line)}</p>" for line in notes))
    lat_ms = _latency_ms(rec.joint_states, rec.joint_torques)
    if len(lat_ms):
        parts.append(_div(_histogram(lat_ms, "one-way latency (recorder receive - stamp)", "ms"),
                          "latency-histogram", "histogram"))
    torques = rec.joint_torques
    if torques is not None and len(torques) > 1:
        gaps = np.diff(np.sort(torques.log_ns)) / 1e6
        parts.append(_div(_histogram(gaps, "joint_torques inter-arrival time (receive)", "ms"),
                          "delivery-histogram", "histogram"))
    return parts


def render(report, rec, ref, bag_info, code: int, latency_lines: list[str]) -> str:
    """The whole page (str). report: offline.check.CheckReport; rec: the bag's Recording."""
    arm = report.model.arm
    parts = _head(bag_info, report.failures, report.warnings, code)
    parts.append(f"<p>{bag_info.message_count} messages, {len(report.movements)} movements; model "
                 f"{html.escape(report.model.describe())}; machine: "
                 f"{html.escape(report.load.describe())}</p>")
    parts.append("<h2>Errors per movement</h2><p class='note'>NRMSE in %: pipeline = recorded vs the "
                 "same model at the exact state (RMSE / the DOF's peak-to-peak over the movement); "
                 "model = recorded vs the OpenSim reference, both low-passed at 6 Hz.</p>")
    parts.append(_table(["id", "name", "elbow", "samples", "state err (rad)", "pipeline NRMSE (%)",
                         "worst DOF", "model NRMSE (%)", "worst DOF", "note"],
                        movement_rows(report), numeric_from=3))
    if report.model_groups:
        parts.append("<h2>Model error by DOF group</h2><p class='note'>NRMSE (%): RMSE / the DOF's "
                     "largest reference peak-to-peak over the library.</p>")
        parts.append(_table(["group", "n", "median", "mean", "max"],
                            [[g, str(s["n"]), _pct(s["median"]), _pct(s["mean"]), _pct(s["max"])]
                             for g, s in report.model_groups.items()]))
    parts += _delivery(report.delivery, rec, latency_lines)
    parts.append("<h2>Torques per movement</h2>")
    for res in report.movements:
        if res.samples == 0:
            parts.append(f"<p>movement {res.id} (index {res.index}): no joint_torques in its window</p>")
            continue
        fig = movement_figure(res, rec.joint_torques, arm, ref, report.model.percentile)
        parts.append(_div(fig, f"movement-{res.index}", "movement-plot"))
    return page(f"check_bag {bag_info.path.name}", "\n".join(parts))


#: A segment (any length) is thinned to this many points per trace.
SEGMENT_POINTS = 2000


def segment_figure(report) -> go.Figure:
    """A recording without movement markers: recorded torques vs the model's torques at the
    6 Hz-filtered recorded positions (bag/score.py), one row per DOF group."""
    names = report.joint_names
    stamps, rec, ref = report.compared
    keep = np.unique(np.linspace(0, len(stamps) - 1, min(len(stamps), SEGMENT_POINTS)).round()
                     .astype(int))
    t = (stamps[keep] - stamps[0]) / 1e9
    return _dof_group_figure(
        names, [(t, rec[keep], "recorded", None, 1.5),
                (t, ref[keep], f"reference ({report.cutoff_hz:g} Hz positions)", "dash", 1)],
        "time since the first compared sample (s)",
        "the recording as one segment: solid recorded, dashed reference")


def render_segment(report, rec, bag_info, code: int) -> str:
    """The page of a recording without markers (report: offline.score.ScoreReport)."""
    names = report.joint_names
    parts = _head(bag_info, report.failures, report.warnings, code)
    parts.append(f"<p>{bag_info.message_count} messages, no movement markers: scored as one "
                 f"segment of {report.duration_s:.1f} s ({report.samples} compared samples); model "
                 f"{html.escape(report.model.describe())}; torque lag median "
                 f"{_num(report.lag_median_ms, '.1f')} ms</p>")
    parts.append("<h2>Errors per DOF</h2>")
    parts.append(_table(["DOF", "RMSE (N·m)", "NRMSE (%)", "lag (ms)"],
                        [[n, _num(report.rmse[j], ".4f"), _pct(report.nrmse[j]),
                          _num(report.lag_ms[j], ".1f")] for j, n in enumerate(names)]))
    parts += _delivery(report.delivery, rec, [])
    if report.compared is not None:
        parts.append("<h2>Torques</h2>")
        parts.append(_div(segment_figure(report), "segment-0", "movement-plot"))
    return page(f"check_bag {bag_info.path.name}", "\n".join(parts))


def page(title: str, body: str) -> str:
    return ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
            f"<title>{html.escape(title)}</title><style>{CSS}</style>"
            f"<script type='text/javascript'>{get_plotlyjs()}</script></head>"
            f"<body>\n{body}\n</body></html>\n")


def write_html(path: Path, text: str) -> None:
    """Write via a temporary file and rename: a failed write never leaves half a report."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
