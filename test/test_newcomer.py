"""The newcomer's rough edges (issue 17 item 9), each one as it was met: parameter texts,
the torque listener at 100 Hz, an output that exists, the model stated."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pytest
from test_node_params import SPECS
from test_opensim_files import write_file

from forearm_dynamics.cli.mot_to_bag import main as mot_to_bag
from forearm_dynamics.nodes import bag_player

pytestmark = pytest.mark.unit

ALL_SPECS = {**SPECS, "bag_player": bag_player.SPECS}


@pytest.mark.parametrize("node", sorted(ALL_SPECS))
def test_parameter_descriptions_are_sentences(node) -> None:
    """`ros2 param describe` read "two types Can be changed at runtime", "model kind One of:":
    each part of a description is its own sentence, for every parameter of every node (an
    unknown parameter's 'did you mean': test_node_catalog, test_faults_params)."""
    for spec in ALL_SPECS[node]:
        text = spec.text()
        joined = re.search(r"[^.?!] (One of:|Can be changed|Read-only)", text)
        assert joined is None, (node, spec.name, text)
        assert text.endswith("."), (node, spec.name, text)


def _listener():
    path = Path(__file__).resolve().parents[1] / "examples" / "torque_listener.py"
    spec = importlib.util.spec_from_file_location("torque_listener_example", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("rate_hz", [30.0, 100.0, 1000.0])
def test_torque_listener_learns_the_stream_rate(rate_hz) -> None:
    """examples/torque_listener.py assumed 1 kHz: a 100 Hz stream was 299 "gaps" of 300."""
    watch_cls = _listener().StampWatch
    period = round(1e9 / rate_hz)
    steady = watch_cls()
    for k in range(300):
        steady.add(10**18 + k * period)
    assert (steady.gaps, steady.out_of_order) == (0, 0)
    missing = watch_cls()
    for k in [*range(150), *range(153, 300)]:  # three samples lost
        missing.add(10**18 + k * period)
    missing.add(10**18)  # and a restart
    assert (missing.gaps, missing.out_of_order) == (1, 1)
    told = watch_cls(expected_hz=1000.0)  # the old assumption, now only when asked
    for k in range(300):
        told.add(10**18 + k * period)
    assert told.gaps == (0 if rate_hz == 1000.0 else 299)


def test_refusing_to_overwrite_names_the_option(tmp_path, capsys) -> None:
    mot, bag = tmp_path / "a.mot", tmp_path / "a.mcap"
    write_file(mot, "motion", degrees=True, rate=100.0, seconds=0.2)
    assert mot_to_bag([str(mot), str(bag)]) == 0
    capsys.readouterr()
    assert mot_to_bag([str(mot), str(bag)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [(f"mot_to_bag: error: {bag} exists already; refusing to overwrite it "
                   "(--overwrite replaces it)")]
    assert mot_to_bag([str(mot), str(bag), "--overwrite"]) == 0
