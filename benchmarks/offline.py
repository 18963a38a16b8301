"""Offline figures: reproduce_paper wall time (a real run of the console script)."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

from forearm_dynamics.processes import BIN


def reproduce_paper(work: Path, env: dict[str, str], timeout: float = 600.0) -> dict:
    out = work / "paper"
    t0 = time.perf_counter()
    proc = subprocess.run([str(BIN / "reproduce_paper"), "--out", str(out)], env=env,
                          capture_output=True, text=True, timeout=timeout, check=False)
    wall = time.perf_counter() - t0
    return {"wall_time_s": wall, "exit_code": proc.returncode,
            "outputs": sorted(p.name for p in out.iterdir()) if out.is_dir() else [],
            "stderr_tail": proc.stderr[-500:] if proc.returncode else ""}
