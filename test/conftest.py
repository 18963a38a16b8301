"""Shared fixtures: DDS stays on loopback for every test in this folder."""

import ast
import os
import re
from pathlib import Path

import pytest
import rosproc

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("HOME", "/tmp")

#: The tiers a test is in (setup.cfg registers them; docs/testing.md says which to use).
TIERS = ("unit", "cli", "ros", "faults", "hosts", "ros_tools", "slow")


def _marks_in(path: Path) -> set[str]:
    """Every pytest.mark.<name> a test module's source names (its pytestmark, its decorators)."""
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"))
    except (OSError, SyntaxError):
        return set(TIERS)  # let pytest import it and say what is wrong
    return {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)
            and isinstance(n.value, ast.Attribute) and n.value.attr == "mark"}


def pytest_ignore_collect(collection_path: Path, config) -> bool | None:
    """`-m unit` (or `-m "a or b"`) does not import the modules that cannot hold a selected
    test: importing every ROS test module costs more than the unit tests take to run."""
    expr = (config.getoption("markexpr", "") or "").strip()
    names = re.split(r"\s+or\s+", expr)
    if not expr or not all(n.isidentifier() and n not in ("and", "not") for n in names):
        return None
    if collection_path.suffix != ".py" or not collection_path.name.startswith("test_"):
        return None
    return not set(names) & _marks_in(collection_path) or None


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items) -> None:
    """A test marked `slow` is not a unit test, even in a unit module: `pytest -m unit` is
    what a developer runs on every change, so it must stay fast. The module's tier markers
    move down onto its tests (before `-m` selects), `unit` left off the slow ones."""
    modules = {}
    for item in items:
        module = item.getparent(pytest.Module)
        if module is not None:
            modules.setdefault(module, []).append(item)
    for module, tests in modules.items():
        tiers = [m for m in module.own_markers if m.name in TIERS]
        if not any(m.name == "unit" for m in tiers):
            continue
        module.own_markers[:] = [m for m in module.own_markers if m.name not in TIERS]
        for item in tests:
            for mark in tiers:
                if not (mark.name == "unit" and item.get_closest_marker("slow")):
                    item.add_marker(mark.name)


def pytest_runtest_setup(item) -> None:
    """A test in no tier fails, naming the fix: `pytest -m unit` would never run it, and no
    one would know what it needs (processes, DDS, root)."""
    if not any(item.iter_markers(name) for name in TIERS):
        pytest.fail(f"{item.nodeid}: in no test tier; set `pytestmark = pytest.mark.<tier>` in "
                    f"its module, one of {', '.join(TIERS)} (setup.cfg, docs/testing.md)",
                    pytrace=False)


@pytest.fixture
def procs():
    """rosproc.Procs for one test: every process started through it is killed at teardown."""
    p = rosproc.Procs()
    yield p
    p.close()


@pytest.fixture(scope="module")
def module_procs():
    """rosproc.Procs shared by a module's tests (a node a module-scoped harness keeps)."""
    p = rosproc.Procs()
    yield p
    p.close()


@pytest.fixture(autouse=True, scope="module")
def _test_domain_leases():
    """Domains leased by a module's tests are held until its last process has ended: this
    autouse fixture is set up first, so it is torn down after the module's own fixtures."""
    yield
    rosproc.release_test_domains()


@pytest.fixture(scope="session")
def paper_results() -> dict:
    """results/paper/results.json as committed (the analysis' numbers the docs quote)."""
    import json

    path = Path(__file__).resolve().parents[1] / "results" / "paper" / "results.json"
    return json.loads(path.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def mm():
    """The shipped muscle model (the muscle tests' subject; module-scoped: its surrogate keeps
    per-sample scratch)."""
    from forearm_dynamics.muscles import load_muscle_model

    return load_muscle_model()


@pytest.fixture(scope="module")
def arm():
    """The segmented arm (a test module may define its own `arm`: the model it needs)."""
    from forearm_dynamics import build_model

    return build_model("segmented")
