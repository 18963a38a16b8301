"""check_bag --html: the muscles' section, when the bag holds muscle_forces (muscle_node,
bag_muscles): per muscle its peak and mean activation and peak force (every sample), the
reserves' use, and one figure of the activations over time (the muscles whose peak reaches
SHOWN_PEAK; thinned like the torque figures). A page without muscles is left as it is.
"""

from __future__ import annotations

import html

import numpy as np
import plotly.graph_objects as go

from ..codec.jointstate import read_joint_series
from ..description import JOINT_NAMES
from .html_report import MAX_POINTS, _div, _table, _thin

SHOWN_PEAK = 0.02  # muscles drawn: peak activation at least this
TOPIC, RESERVES = "muscle_forces", "muscle_reserves"


def muscle_section(bag) -> str:
    """The section's HTML ('' when the bag has no muscle_forces)."""
    if bag.info.find_topic(TOPIC) is None:
        return ""
    s = read_joint_series(bag, TOPIC, None, effort=True)
    if not len(s):
        return ""
    order = np.argsort(s.stamp_ns, kind="stable")
    t = (s.stamp_ns[order] - s.stamp_ns[order][0]) / 1e9
    a, f = s.position[order], s.effort[order]
    peak, mean, fmax = np.nanmax(a, axis=0), np.nanmean(a, axis=0), np.nanmax(f, axis=0)
    rows = [[html.escape(m), f"{peak[i]:.3f}", f"{mean[i]:.3f}", f"{fmax[i]:.1f}"]
            for i, m in sorted(enumerate(s.joint_names), key=lambda x: -peak[x[0]])]
    parts = ["<h2>Muscles</h2>",
             (f"<p class='note'>{len(s)} messages on {html.escape(s.topic)} (activation 0..1 and "
              "tendon force of every muscle: static optimisation of each torque sample).</p>"),
             _table(["muscle", "peak activation", "mean activation", "peak force (N)"], rows)]
    if bag.info.find_topic(RESERVES) is not None:
        r = read_joint_series(bag, RESERVES, JOINT_NAMES, effort=True)
        big = np.nanmax(np.abs(r.effort), axis=0) if len(r) else np.zeros(len(JOINT_NAMES))
        parts.append("<p class='note'>Reserves (torque the muscles did not carry), largest |r| "
                     "per joint in N·m: " + ", ".join(f"{j} {big[k]:.3f}" for k, j in
                                                     enumerate(JOINT_NAMES) if big[k] > 1e-3)
                     + (" (none above 0.001)" if not (big > 1e-3).any() else "") + "</p>")
    keep = _thin(len(t)) if len(t) > MAX_POINTS * 8 else np.arange(len(t))
    fig = go.Figure()
    for i, m in enumerate(s.joint_names):
        if peak[i] >= SHOWN_PEAK:
            fig.add_trace(go.Scattergl(x=t[keep].astype(np.float32), y=a[keep, i].astype(np.float32),
                                       mode="lines", name=m))
    fig.update_layout(height=420, xaxis_title="s from the first muscle_forces stamp",
                      yaxis_title="activation", title=f"activations (peak >= {SHOWN_PEAK})")
    parts.append(_div(fig, "muscles", "movement-plot"))
    return "\n".join(parts)


def with_muscles(page_text: str, bag) -> str:
    """The page with the muscles' section before its end (unchanged without muscles)."""
    section = muscle_section(bag)
    if not section:
        return page_text
    return page_text.replace("\n</body>", "\n" + section + "\n</body>", 1)
