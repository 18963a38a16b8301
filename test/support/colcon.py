"""The one colcon build of a clean copy of the checkout (test_colcon, test_ros_tools).

A clean copy: the files git tracks, as they are in the working tree (no .venv, no build
outputs), under <ws>/src/forearm_dynamics, built by the venv's colcon as a user would."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def colcon_build_clean_copy(ws: Path, venv_bin: Path, timeout: float) -> Path:
    """Build it in `ws`; return the workspace's install/ directory (AssertionError with the
    build's output tail if colcon fails)."""
    files = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True,
                           check=True).stdout.split()
    for f in files:
        (ws / "src" / "forearm_dynamics" / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / f, ws / "src" / "forearm_dynamics" / f)
    env = {**os.environ, "PATH": f"{venv_bin}:{os.environ.get('PATH', '')}"}
    r = subprocess.run([str(venv_bin / "colcon"), "build", "--base-paths", "src"], cwd=ws, env=env,
                       capture_output=True, text=True, timeout=timeout, check=False)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return ws / "install"
