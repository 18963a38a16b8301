"""One source per parameter: config/nodes/<node>.yaml and docs/nodes.md are what the nodes'
Spec tables generate (nodes/catalog.py), values included, for every node with parameters."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from forearm_dynamics.nodes import catalog
from forearm_dynamics.nodes.spec import Spec, did_you_mean, load_defaults

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("path", sorted(catalog.expected(), key=str), ids=lambda p: p.name)
def test_committed_file_is_the_generated_one(path: Path) -> None:
    want = catalog.expected()[path]
    assert path.is_file(), f"{path} missing: run `{catalog.COMMAND}`"
    assert path.read_text(encoding="utf-8") == want, f"{path} is stale: run `{catalog.COMMAND}`"


@pytest.mark.parametrize("node", list(catalog.NODES))
def test_the_defaults_a_node_reads_are_its_specs(node: str) -> None:
    """What Params reads at start-up (the installed file) equals each Spec's default, in type too."""
    specs = catalog.specs_of(node)
    names = [s.name for s in specs]
    assert len(names) == len(set(names)), f"{node}: a parameter defined twice"
    read = load_defaults(node)
    assert list(read) == names
    for s in specs:
        assert read[s.name] == s.default and type(read[s.name]) is type(s.default), s.name


def test_every_node_executable_with_parameters_is_in_the_catalog() -> None:
    """A node that declares parameters (Params(...)) is listed, so its file is generated."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    exes = next(n.value for n in ast.walk(tree) if isinstance(n, ast.Assign)
                and getattr(n.targets[0], "id", "") == "EXECUTABLES")
    nodes = {k.value for k, v in zip(exes.keys, exes.values, strict=True)
             if ".nodes." in v.value}
    assert nodes <= set(catalog.NODES) | set(catalog.SAME_PARAMETERS), nodes - set(catalog.NODES)
    assert set(catalog.SAME_PARAMETERS.values()) <= set(catalog.NODES)


def test_descriptions_are_sentences() -> None:
    s = Spec("body_size", 50, "body size; the one parameter that takes two types", live=True,
             dynamic=True)
    assert s.text() == ("body size; the one parameter that takes two types. Can be changed at "
                        "runtime.")
    k = Spec("model", "segmented", "model kind", choices=("segmented", "solid"))
    assert k.text() == "model kind. One of: segmented, solid. Read-only: set at start-up."
    assert Spec("rate", 1.0, "rate", "Hz", 0.0, 10.0).text() == \
        "rate [Hz]. Range [0, 10]. Read-only: set at start-up."


def test_did_you_mean() -> None:
    names = [s.name for s in catalog.specs_of("torque_node")]
    assert did_you_mean("bodysize", names) == " (did you mean body_size?)"
    assert did_you_mean("banana", names) == ""


def test_settings_dataclasses_read_only_declared_parameters() -> None:
    """Each node's settings dataclass (from_params, as rosbag2's PlayOptions) has a field per
    parameter it reads, named as the Spec: a field without a Spec cannot slip in, and the
    defaults of the Specs make valid settings (built ROS-free, from a dict)."""
    import dataclasses

    from forearm_dynamics.nodes import bag_player, bag_recorder, torque_config

    for cls, specs in ((bag_player.PlaySettings, bag_player.SPECS),
                       (bag_recorder.RecordSettings, bag_recorder.SPECS),
                       (torque_config.OutputSettings, torque_config.OUTPUT_SPECS)):
        names = {s.name for s in specs}
        fields = {f.name for f in dataclasses.fields(cls)}
        assert fields <= names, (cls.__name__, fields - names)
        made = cls.from_values({s.name: s.default for s in specs})
        assert {f: getattr(made, f) for f in fields} == {s.name: s.default for s in specs
                                                         if s.name in fields}
