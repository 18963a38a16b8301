"""Where the package's YAML files live, in a checkout, a pip install or a colcon install."""

from __future__ import annotations

import os
import sys
from functools import lru_cache
from pathlib import Path

PACKAGE = "forearm_dynamics"


@lru_cache(maxsize=1)
def config_dir() -> Path:
    """The `config/` folder: env override, checkout, pip data_files, then the ament index."""
    candidates = []
    if os.environ.get("FOREARM_DYNAMICS_CONFIG"):
        candidates.append(Path(os.environ["FOREARM_DYNAMICS_CONFIG"]))
    here = Path(__file__).resolve().parent
    candidates.append(here.parent / "config")  # source checkout / editable install
    # colcon or pip: <prefix>/lib/pythonX.Y/site-packages/<pkg> -> <prefix>/share/<pkg>
    if len(here.parents) > 3:
        candidates.append(here.parents[3] / "share" / PACKAGE / "config")
    candidates.append(Path(sys.prefix) / "share" / PACKAGE / "config")  # pip, other layouts
    for path in candidates:
        if (path / "model.yaml").is_file():
            return path
    try:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory(PACKAGE)) / "config"
        if (path / "model.yaml").is_file():
            return path
    except Exception:  # noqa: BLE001, S110 - the ament index is optional outside colcon installs
        pass
    raise FileNotFoundError(
        "forearm_dynamics: cannot find config/model.yaml; looked in "
        + ", ".join(str(p) for p in candidates)
        + " (set FOREARM_DYNAMICS_CONFIG to the folder that holds it)"
    )


def config_file(name: str) -> Path:
    """Model and analysis data: config/<name> (model.yaml, body_sizes.yaml, movements.yaml ...)."""
    return config_dir() / name


def node_config_file(node: str) -> Path:
    """A node's parameter file: config/nodes/<node>.yaml (generated from its Specs)."""
    return config_dir() / "nodes" / f"{node}.yaml"
