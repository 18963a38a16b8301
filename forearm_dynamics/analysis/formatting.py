"""Number formatting shared by the generated tables (one place for the units shown)."""

from __future__ import annotations

import math


def pc(x) -> str:
    """A fraction as a percentage, 3 significant digits (the README's and tables' unit)."""
    if x is None or not math.isfinite(x):
        return "–"
    v = 100 * x
    return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"


def nm(x) -> str:
    return "–" if x is None else f"{x:.3g}"


def mm(v) -> str:
    return f"{1000 * v[0]:.1f}, {1000 * v[1]:.1f}"
