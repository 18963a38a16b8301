"""Paired statistics of per-movement errors: is model A's error smaller than model B's?

The 65 movements are not 65 independent samples: the 5 elbow conditions of one hand
movement share its hand and pro/sup motion. So the confidence interval of a mean difference
is a cluster bootstrap (resample the 13 hand movements with replacement, keep each one's 5
conditions together). The Wilcoxon signed-rank test (scipy.stats.wilcoxon, two-sided) is
reported beside it as the paper-style test on the paired movements; its p-value treats the
movements as independent, which the bootstrap does not: read them together.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from ..movements import movement_library

N_BOOT = 4000
SEED = 20240521  # fixed: results.json reproduces exactly
CI = 0.95


def clusters_of(movement_ids) -> np.ndarray:
    """Cluster label (hand movement number) of each movement id."""
    lib = movement_library()
    return np.array([lib[i - 1].hand_number for i in movement_ids])


def cluster_bootstrap_mean(values: np.ndarray, clusters: np.ndarray, n_boot: int = N_BOOT,
                           seed: int = SEED) -> tuple[float, float]:
    """Percentile CI of the mean of `values` (finite ones), resampling whole clusters."""
    v = np.asarray(values, float)
    ok = np.isfinite(v)
    v, c = v[ok], np.asarray(clusters)[ok]
    labels = np.unique(c)
    if labels.size < 2:
        return float("nan"), float("nan")
    sums = np.array([v[c == k].sum() for k in labels])
    counts = np.array([(c == k).sum() for k in labels], float)
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, labels.size, size=(n_boot, labels.size))
    means = sums[pick].sum(axis=1) / counts[pick].sum(axis=1)
    lo, hi = np.percentile(means, [100 * (1 - CI) / 2, 100 * (1 + CI) / 2])
    return float(lo), float(hi)


def paired(a, b, clusters) -> dict:
    """a, b: (n,) errors of two models on the same movements (NaN = left out: the pair is
    dropped). Difference d = a - b; negative = A better."""
    a, b = np.asarray(a, float).reshape(-1), np.asarray(b, float).reshape(-1)
    c = np.asarray(clusters).reshape(-1)
    ok = np.isfinite(a) & np.isfinite(b)
    d = a[ok] - b[ok]
    n = int(d.size)
    out = {"n": n, "clusters": int(np.unique(c[ok]).size),
           "mean_a": float(a[ok].mean()) if n else None, "mean_b": float(b[ok].mean()) if n else None,
           "mean_difference": float(d.mean()) if n else None,
           "median_difference": float(np.median(d)) if n else None,
           "wins_a": int((d < 0).sum()), "wins_b": int((d > 0).sum()), "ties": int((d == 0).sum())}
    lo, hi = cluster_bootstrap_mean(d, c[ok]) if n else (float("nan"), float("nan"))
    out["ci95_mean_difference"] = [lo, hi]
    if n >= 6 and np.any(d != 0):
        w = stats.wilcoxon(a[ok], b[ok], zero_method="wilcox", alternative="two-sided")
        out["wilcoxon_statistic"], out["wilcoxon_p"] = float(w.statistic), float(w.pvalue)
    else:
        out["wilcoxon_statistic"] = out["wilcoxon_p"] = None
    return out


def one_sample(values, clusters, threshold: float | None = None) -> dict:
    """Mean with its cluster-bootstrap CI; with a threshold, how many values are under it and
    the Wilcoxon test of (values - threshold) (is the median under the threshold?)."""
    v = np.asarray(values, float).reshape(-1)
    c = np.asarray(clusters).reshape(-1)
    ok = np.isfinite(v)
    out = {"n": int(ok.sum()), "mean": float(v[ok].mean()) if ok.any() else None,
           "median": float(np.median(v[ok])) if ok.any() else None,
           "ci95_mean": list(cluster_bootstrap_mean(v, c))}
    if threshold is not None and ok.any():
        x = v[ok] - threshold
        out["threshold"] = threshold
        out["under"] = int((x < 0).sum())
        w = stats.wilcoxon(x, alternative="less") if np.any(x != 0) and x.size >= 6 else None
        out["wilcoxon_p_median_under"] = None if w is None else float(w.pvalue)
    return out


def significant(row: dict) -> str:
    """A short verdict: which model is better, and whether the CI excludes 0."""
    lo, hi = row["ci95_mean_difference"]
    if lo is None or hi is None or not np.isfinite(lo) or not np.isfinite(hi):
        return "n/a"
    if hi < 0:
        return "A better (CI < 0)"
    if lo > 0:
        return "B better (CI > 0)"
    return "no difference (CI spans 0)"
