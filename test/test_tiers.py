"""Every test module says its tier (`pytestmark`), so `pytest -m unit` runs what is fast and
process-free and nothing falls between the tiers."""

import ast
import configparser
from pathlib import Path

import pytest
from conftest import TIERS

pytestmark = pytest.mark.unit

HERE = Path(__file__).resolve().parent


def _pytestmark_names(path: Path) -> list[str]:
    """The marker names of a module's top-level `pytestmark = pytest.mark.x` (or a list)."""
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "pytestmark"
                                                for t in node.targets):
            values = node.value.elts if isinstance(node.value, ast.List | ast.Tuple) else [node.value]
            return [v.attr for v in values if isinstance(v, ast.Attribute)]
    return []


def test_every_module_is_in_a_registered_tier() -> None:
    cfg = configparser.ConfigParser()
    cfg.read(HERE.parent / "setup.cfg")
    registered = {line.split(":")[0].strip() for line in cfg["tool:pytest"]["markers"].splitlines()
                  if line.strip()}
    assert set(TIERS) <= registered and "slow" in registered
    modules = sorted(HERE.glob("test_*.py"))
    assert len(modules) > 40
    untiered = [p.name for p in modules if not set(_pytestmark_names(p)) & set(TIERS)]
    assert not untiered, f"set `pytestmark = pytest.mark.<tier>` ({', '.join(TIERS)}) in {untiered}"
    unknown = {p.name: n for p in modules for n in _pytestmark_names(p) if n not in registered}
    assert not unknown, unknown


def test_the_check_sees_a_module_without_a_tier(tmp_path) -> None:
    (tmp_path / "test_x.py").write_text("import pytest\n\ndef test_a():\n    pass\n")
    (tmp_path / "test_y.py").write_text("import pytest\n\npytestmark = [pytest.mark.ros, "
                                        "pytest.mark.slow]\n")
    assert _pytestmark_names(tmp_path / "test_x.py") == []
    assert _pytestmark_names(tmp_path / "test_y.py") == ["ros", "slow"]
