"""`colcon build` (colcon from PyPI) installs every executable where `ros2 run` looks."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from support.colcon import colcon_build_clean_copy

pytestmark = [pytest.mark.cli, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent


def _executables() -> list[str]:
    text = (REPO / "setup.py").read_text()
    block = text[text.index("EXECUTABLES = {"):text.index("}", text.index("EXECUTABLES = {"))]
    return [line.split('"')[1] for line in block.splitlines() if line.strip().startswith('"')]


@pytest.fixture(scope="module")
def install(tmp_path_factory):
    if shutil.which("colcon", path=str(VENV_BIN)) is None:
        pytest.fail("colcon is not installed in the venv (make setup installs it)")
    return colcon_build_clean_copy(tmp_path_factory.mktemp("ws"), VENV_BIN, 300) / "forearm_dynamics"


def test_every_executable_under_lib(install):
    exes = _executables()
    assert len(exes) >= 8
    for exe in exes:
        path = install / "lib" / "forearm_dynamics" / exe
        assert path.is_file() and os.access(path, os.X_OK), exe
    assert (install / "share" / "ament_index" / "resource_index" / "packages" / "forearm_dynamics").is_file()


def test_installed_executable_runs_from_the_install_tree(install, tmp_path):
    """The installed copy finds its config and data in share/ and site-packages, not the repo."""
    site = next(install.glob("lib/python*/site-packages"))
    env = {k: v for k, v in os.environ.items() if k != "FOREARM_DYNAMICS_CONFIG"}
    env["PYTHONPATH"] = str(site)
    out = tmp_path / "arm.urdf"
    code = ("import sys, forearm_dynamics, forearm_dynamics.paths as p; "
            f"assert str(forearm_dynamics.__file__).startswith({str(site)!r}), forearm_dynamics.__file__; "
            "print(p.config_dir())")
    r = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True,
                       text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == str(install / "share" / "forearm_dynamics" / "config")
    from forearm_dynamics.nodes.catalog import NODES  # every node's parameter file, apart
    nodes = install / "share" / "forearm_dynamics" / "config" / "nodes"
    assert sorted(p.stem for p in nodes.glob("*.yaml")) == sorted(NODES)
    assert not (install / "share" / "forearm_dynamics" / "config" / "torque_node.yaml").exists()
    r = subprocess.run([str(install / "lib" / "forearm_dynamics" / "export_urdf"), "--model", "solid",
                        "-o", str(out)], env=env, cwd=tmp_path, capture_output=True, text=True,
                       timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert "<robot" in out.read_text()


def test_launch_files_installed_as_data(install):
    """colcon installs launch/*.launch.py where `ros2 launch forearm_dynamics` finds them; each
    defines generate_launch_description (read as text: `launch` is not installed here, and
    the package never imports it)."""
    import ast

    installed = sorted(p.name for p in (install / "share" / "forearm_dynamics" / "launch").glob("*.py"))
    assert installed == sorted(p.name for p in (REPO / "launch").glob("*.launch.py"))
    assert {"torque_node.launch.py", "record.launch.py", "demo.launch.py", "closed_loop.launch.py",
            "viz.launch.py"} <= set(installed)
    for name in installed:
        tree = ast.parse((install / "share" / "forearm_dynamics" / "launch" / name).read_text())
        assert "generate_launch_description" in {f.name for f in tree.body
                                                 if isinstance(f, ast.FunctionDef)}, name
    for example in ("closed_loop.py", "closed_loop_report.py"):  # the launch file runs the first
        assert (install / "share" / "forearm_dynamics" / "examples" / example).is_file()
