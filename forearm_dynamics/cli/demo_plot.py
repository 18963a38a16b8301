"""The demo's picture: recorded torques of one movement against the model and the reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import JOINT_NAMES, build_model, get_movement
from ..analysis.plots import _pyplot
from ..bag import open_bag
from ..offline.check import LATE_MAX_NS
from ..offline.recording import read_recording
from ..reference import load_reference

SHOW = ("pro_sup", "elbow_flexion", "wrist_flexion", "index_mcp_flexion")


def movement_window(markers: list, index: int, duration_s: float) -> tuple[int, int]:
    """[t0, end) in stamp ns of the marker at `index`: the samples check_bag counts for it.

    Up to the next marker, at most duration + LATE_MAX_NS: the next movement's first sample
    can carry a stamp before t0 + duration (drawn with this movement it looks like a torque
    spike at the end), and a late publisher's catch-up samples of this movement a stamp after.
    """
    t0 = markers[index].t0_ns
    end = t0 + round(duration_s * 1e9) + LATE_MAX_NS
    if index + 1 < len(markers):
        end = min(end, markers[index + 1].t0_ns)
    return t0, end


def draw(bag_path: Path, out: Path, movement_id: int = 3) -> None:
    rec = read_recording(open_bag(bag_path), JOINT_NAMES)
    index = next((k for k, m in enumerate(rec.markers) if m.id == movement_id), 0)
    marker = rec.markers[index]
    mv = get_movement(marker.id)
    t0, end = movement_window(rec.markers, index, mv.duration)
    tq = rec.joint_torques
    sel = (tq.stamp_ns >= t0) & (tq.stamp_ns < end)
    t = (tq.stamp_ns[sel] - t0) * 1e-9
    exact = build_model("segmented").inverse_dynamics(*mv.evaluate(t))
    ref = load_reference()
    ref_t = ref.times[: int(mv.duration * ref.rate_hz)]
    ref_tau = ref.torques(mv.id, 50)
    latency_ms = (tq.log_ns - tq.stamp_ns) * 1e-6
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(SHOW) + 1, figsize=(18, 3.6))
    for ax, name in zip(axes, SHOW, strict=False):
        j = JOINT_NAMES.index(name)
        ax.plot(ref_t, ref_tau[:, j], color="0.6", lw=3, label="anatomical (OpenSim)")
        ax.plot(t, exact[:, j], "k--", lw=1, label="segmented, exact state")
        ax.plot(t, tq.effort[sel, j], color="tab:red", lw=1, label="torque_node (recorded)")
        ax.set_title(name)
        ax.set_xlabel("time (s)")
    axes[0].set_ylabel("torque (N·m)")
    axes[0].legend(fontsize=7)
    axes[-1].hist(latency_ms[np.isfinite(latency_ms)], bins=100, color="tab:blue")
    axes[-1].set_yscale("log")
    axes[-1].set_xlabel("one-way latency (ms)")
    axes[-1].set_title("latency, all messages")
    fig.suptitle(f"Movement {mv.id}: {mv.name}, {mv.elbow} — recorded by the demo")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
