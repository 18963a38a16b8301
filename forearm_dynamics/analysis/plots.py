"""Analogues of the paper's Fig. 3, 4 and 5 (matplotlib, PNG)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..description import DOF_GROUPS, JOINT_NAMES

_IDX = {n: i for i, n in enumerate(JOINT_NAMES)}
FLOOR_PCT = 1e-3  # NRMSE values under this (%) are drawn at it, so the log axis stays readable
COLORS = {"anatomical": "black", "solid": "tab:blue", "paper": "tab:orange",
          "parallel": "tab:green", "oblique": "tab:red"}
STYLES = {"anatomical": "-", "solid": "-", "paper": "--", "parallel": "-.", "oblique": ":"}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only, no screen
    import matplotlib.pyplot as plt

    return plt


def figure3(path: Path, t: np.ndarray, q: np.ndarray, qd: np.ndarray,
            torques: dict[str, dict[str, np.ndarray]], title: str) -> None:
    """Pro/sup angle and velocity, then pro/sup torque of the three models per body size."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 4, figsize=(17, 4.2), constrained_layout=True)
    j = _IDX["pro_sup"]
    ax = axes[0]
    a1 = ax.plot(t, np.rad2deg(q[:, j]), "k", label="angle (deg)")
    ax2 = ax.twinx()
    a2 = ax2.plot(t, np.rad2deg(qd[:, j]), "k--", label="velocity (deg/s)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("pro/sup angle (deg)")
    ax2.set_ylabel("pro/sup velocity (deg/s)")
    ax.legend(a1 + a2, [h.get_label() for h in a1 + a2], fontsize=8, loc="upper left")
    ax.set_title("A. kinematics")
    for ax, (label, size) in zip(axes[1:], (("B", "p50"), ("C", "p5"), ("D", "p95")), strict=True):
        for kind, tau in torques[size].items():
            ax.plot(t, tau[:, j], color=COLORS[kind], ls=STYLES[kind], label=kind)
        ax.set_title(f"{label}. {size} body size")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("pro/sup torque (N·m)")
        ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def _dots(ax, series: list[np.ndarray], labels: list[str]) -> None:
    """One dot per movement (and DOF), lines joining the same one; mean, median and IQR.

    Values in %. Values under FLOOR_PCT (movements where the models are identical to
    rounding, e.g. hand torques while the forearm is still) are drawn at FLOOR_PCT.
    """
    data = [np.maximum(100 * np.asarray(s, float), FLOOR_PCT) for s in series]
    from matplotlib.collections import LineCollection

    stacked = np.vstack(data)
    xs = np.arange(len(data), dtype=float)
    # one collection, not one Line2D per movement: 20x faster to lay out and draw
    ax.add_collection(LineCollection([np.column_stack([xs, row]) for row in stacked.T],
                                     colors="0.8", linewidths=0.5, zorder=1))
    for x, d in enumerate(data):
        d = d[np.isfinite(d)]
        ax.scatter(np.full(d.size, x), d, s=6, color="k", zorder=2, rasterized=True)
        if d.size:
            q1, q3 = np.percentile(d, [25, 75])
            ax.add_patch(_rect(x, q1, q3, label="interquartile range" if x == 0 else None))
            ax.plot([x - 0.25, x + 0.25], [d.mean()] * 2, color="red", lw=2, zorder=3,
                    label="mean" if x == 0 else None)
            ax.plot([x - 0.25, x + 0.25], [np.median(d)] * 2, color="navy", lw=1.5, ls="--",
                    zorder=3, label="median" if x == 0 else None)
    ax.set_xticks(range(len(data)), labels, rotation=30, ha="right")
    ax.set_xlim(-0.5, len(data) - 0.5)
    ax.set_yscale("log")


def _rect(x, q1, q3, label=None):
    from matplotlib.patches import Rectangle

    return Rectangle((x - 0.25, q1), 0.5, max(q3 - q1, 1e-12), color="red", alpha=0.2, zorder=0,
                     label=label)


def error_figure(path: Path, errors: dict[str, np.ndarray], title: str) -> None:
    """errors: label -> (M, 20) NRMSE; one panel per DOF group (Fig. 4 and Fig. 5 layout)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(DOF_GROUPS), figsize=(17, 4.4), constrained_layout=True)
    for ax, (group, names) in zip(axes, DOF_GROUPS.items(), strict=True):
        cols = [_IDX[n] for n in names]
        series = [e[:, cols].reshape(-1) for e in errors.values()]
        _dots(ax, series, list(errors))
        ax.set_title(group)
    axes[0].set_ylabel("NRMSE per movement (%, log scale)")
    axes[0].legend(fontsize=7, loc="lower left")
    fig.suptitle(f"{title}\nvalues under {FLOOR_PCT:g} % drawn at {FLOOR_PCT:g} %; movements under "
                 "the normalisation floor left out")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def ci_figure(path: Path, review: dict, models: tuple[str, ...]) -> None:
    """Mean pro/sup NRMSE per model with its 95 % cluster-bootstrap CI, one panel per torque
    reading x scoring window (log scale), and the paired differences of the equal-freedom pairs."""
    plt = _pyplot()
    cases = review["cases"]
    fig, axes = plt.subplots(1, len(cases) + 1, figsize=(19, 4.6), constrained_layout=True)
    for ax, (key, c) in zip(axes, cases.items(), strict=False):
        for x, n in enumerate(models):
            s = c["summary"][n]["prosup_nrmse"]
            lo, hi = s["ci95_mean"]
            m = 100 * s["mean"]
            ax.errorbar([x], [m], yerr=[[m - 100 * lo], [100 * hi - m]], fmt="o", capsize=4,
                        color=COLORS.get(n, "0.3"))
        ax.set_xticks(range(len(models)), models, rotation=35, ha="right", fontsize=8)
        ax.set_yscale("log")
        ax.set_title(key.replace("/", ", "))
    axes[0].set_ylabel("pro/sup NRMSE mean (%), 95 % CI")
    ax = axes[-1]
    labels, k = [], 0
    for key, c in cases.items():
        for p in c["pairs"]["prosup_nrmse"][:3]:
            lo, hi = p["ci95_mean_difference"]
            d = 100 * p["mean_difference"]
            ax.errorbar([d], [k], xerr=[[d - 100 * lo], [100 * hi - d]], fmt="o", capsize=3,
                        color="tab:red" if hi < 0 else "tab:blue" if lo > 0 else "0.4")
            labels.append(f"{p['a']} − {p['b']} ({key})")
            k += 1
    ax.axvline(0, color="k", lw=0.8)
    ax.set_yticks(range(k), labels, fontsize=6)
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_xlabel("A − B, points of NRMSE (95 % CI)")
    ax.set_title("paired differences (red: A better)")
    fig.suptitle("Pro/sup error per model and torque reading / scoring window, 50th percentile; "
                 "CIs: cluster bootstrap over the 13 hand movements")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def lomo_figure(path: Path, lomo: dict) -> None:
    """Leave-one-movement-out: each fitted placement's pro/sup NRMSE held out beside the
    all-65 fit on the same movements, mean with its 95 % cluster-bootstrap CI (log scale)."""
    from .statistics import cluster_bootstrap_mean

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.4), constrained_layout=True)
    clusters = np.repeat(np.arange(1, 14), 5)
    for x, (name, v) in enumerate(lomo["variants"].items()):
        for dx, key, label, color in ((-0.12, "held_out_errors", "held out (13 folds)", "tab:red"),
                                      (0.12, "all_65_fit_errors", "fit on all 65", "0.4")):
            vals = np.array([np.nan if e is None else e for f in v["folds"]
                             for e in f[key]["prosup_nrmse"]], float)
            lo, hi = cluster_bootstrap_mean(vals, clusters)
            m = float(np.nanmean(vals))
            ax.errorbar([x + dx], [100 * m], yerr=[[100 * (m - lo)], [100 * (hi - m)]], fmt="o",
                        capsize=4, color=color, label=label if x == 0 else None)
    ax.set_xticks(range(len(lomo["variants"])), list(lomo["variants"]), rotation=20, ha="right")
    ax.set_yscale("log")
    ax.set_ylabel("pro/sup NRMSE mean (%), 95 % CI")
    ax.set_title("Leave one hand movement out (mirror kept out), fits from neutral")
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
