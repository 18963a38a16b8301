"""Benchmarks of forearm_dynamics, outside the installed package (users' site-packages never
get them). Run from the repository root: `python -m benchmarks` (make bench) and
`python -m benchmarks.soak` (make soak); results are written beside this file."""

from __future__ import annotations

import os
from pathlib import Path

#: The repository root: `python -m benchmarks.<module>` children need it on their path.
ROOT = Path(__file__).resolve().parent.parent


def module_env(env: dict[str, str]) -> dict[str, str]:
    """`env` for a `python -m benchmarks.<module>` child: the repository root on PYTHONPATH."""
    path = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    return {**env, "PYTHONPATH": path}
