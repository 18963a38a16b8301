"""Percentiles and machine facts every benchmark reports."""

from __future__ import annotations

import os
import platform

import numpy as np


def percentiles(values, scale: float = 1.0) -> dict[str, float]:
    v = np.asarray(values, float) * scale
    if v.size == 0:
        return {"n": 0}
    p50, p99, p999 = np.percentile(v, [50, 99, 99.9])
    return {"n": int(v.size), "p50": float(p50), "p99": float(p99), "p99_9": float(p999),
            "max": float(v.max()), "mean": float(v.mean())}


def machine_info() -> dict:
    info = {"machine": platform.machine(), "cores": os.cpu_count(),
            "python": platform.python_version(), "platform": platform.platform()}
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return info
