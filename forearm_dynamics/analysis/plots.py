"""Analogues of the paper's Fig. 3, 4 and 5 (matplotlib, PNG)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..description import DOF_GROUPS, JOINT_NAMES

_IDX = {n: i for i, n in enumerate(JOINT_NAMES)}
FLOOR = 1e-5
COLORS = {"anatomical": "black", "solid": "tab:blue", "segmented": "tab:red"}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only, no screen
    import matplotlib.pyplot as plt

    return plt


def figure3(path: Path, t: np.ndarray, q: np.ndarray, qd: np.ndarray,
            torques: dict[str, dict[str, np.ndarray]], title: str) -> None:
    """Pro/sup angle and velocity, then pro/sup torque of the three models per body size."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 4, figsize=(15, 3.6))
    j = _IDX["pro_sup"]
    ax = axes[0]
    ax.plot(t, np.rad2deg(q[:, j]), "k", label="angle (deg)")
    ax2 = ax.twinx()
    ax2.plot(t, np.rad2deg(qd[:, j]), "k--", label="velocity (deg/s)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("pro/sup angle (deg)")
    ax2.set_ylabel("velocity (deg/s, dashed)")
    ax.set_title("A. kinematics")
    for ax, (label, size) in zip(axes[1:], (("B", "p50"), ("C", "p5"), ("D", "p95")), strict=True):
        for kind, tau in torques[size].items():
            ax.plot(t, tau[:, j], color=COLORS[kind], label=kind)
        ax.set_title(f"{label}. {size}")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("pro/sup torque (N·m)")
    axes[1].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _dots(ax, series: list[np.ndarray], labels: list[str]) -> None:
    """One dot per movement (and DOF), lines joining the same one; mean line and IQR box.

    Values under FLOOR (movements where the two models are identical to rounding, e.g. hand
    torques while the forearm is still) are drawn at FLOOR so the log axis stays readable.
    """
    data = [np.maximum(np.asarray(s, float), FLOOR) for s in series]
    stacked = np.vstack(data)
    for row in stacked.T:
        ax.plot(range(len(data)), row, color="0.8", lw=0.5, zorder=1)
    for x, d in enumerate(data):
        d = d[np.isfinite(d)]
        ax.scatter(np.full(d.size, x), d, s=6, color="k", zorder=2)
        if d.size:
            q1, q3 = np.percentile(d, [25, 75])
            ax.add_patch(_rect(x, q1, q3))
            ax.plot([x - 0.25, x + 0.25], [d.mean()] * 2, color="red", lw=2, zorder=3)
    ax.set_xticks(range(len(data)), labels)
    ax.set_xlim(-0.5, len(data) - 0.5)
    ax.set_yscale("log")


def _rect(x, q1, q3):
    from matplotlib.patches import Rectangle

    return Rectangle((x - 0.25, q1), 0.5, max(q3 - q1, 1e-12), color="red", alpha=0.2, zorder=0)


def error_figure(path: Path, errors: dict[str, np.ndarray], title: str) -> None:
    """errors: label -> (M, 20) NRMSE; one panel per DOF group (Fig. 4 and Fig. 5 layout)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(DOF_GROUPS), figsize=(16, 3.8))
    for ax, (group, names) in zip(axes, DOF_GROUPS.items(), strict=True):
        cols = [_IDX[n] for n in names]
        series = [e[:, cols].reshape(-1) for e in errors.values()]
        _dots(ax, series, list(errors))
        ax.set_title(group)
    axes[0].set_ylabel(f"NRMSE (normalised units, log; < {FLOOR:g} drawn at {FLOOR:g})")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def surface_figure(path: Path, splits: np.ndarray, distal_anterior: np.ndarray,
                   values: np.ndarray, optimum: tuple[float, float]) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4.5))
    mesh = ax.pcolormesh(1000 * distal_anterior, splits, values, shading="auto", cmap="viridis")
    fig.colorbar(mesh, ax=ax, label="objective (pro/sup + elbow NRMSE, global)")
    ax.plot(1000 * optimum[1], optimum[0], "r*", ms=12, label="optimum")
    ax.set_xlabel("distal axis offset, anterior (mm)")
    ax.set_ylabel("split fraction")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
