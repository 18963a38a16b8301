"""The shipped gold-standard torques: regenerated from OpenSim, and matched by Pinocchio.

Only the regeneration needs OpenSim (the optional [reference] extra); the rest reads the
shipped file and runs everywhere."""

import numpy as np
import pytest

from forearm_dynamics import build_model, get_movement
from forearm_dynamics.reference import load_reference

pytestmark = pytest.mark.unit


def test_shipped_file_covers_everything():
    ref = load_reference()
    assert ref.body_sizes == (5, 50, 95)
    assert ref.movement_ids == tuple(range(1, 66))
    assert ref.rate_hz == 1000.0
    assert ref.meta["engine"] == "opensim"
    assert ref.torques_all.shape == (3, 65, 1500, 20)
    assert np.isfinite(ref.torques_all).all()


@pytest.mark.parametrize(("size", "movement_id"), [(5, 4), (50, 3), (50, 37), (95, 65)])
def test_regenerated_matches_shipped(size, movement_id):
    pytest.importorskip("opensim")
    from forearm_dynamics.cli.make_reference import reference_torques

    fresh = reference_torques([size], [movement_id], 1000.0)[0, 0]
    shipped = load_reference().torques(movement_id, size)
    assert np.abs(fresh - shipped).max() < 1e-9


@pytest.mark.parametrize("size", [5, 50, 95])
def test_pinocchio_anatomical_matches_reference(size):
    model = build_model("anatomical", body_size=size)
    ref = load_reference()
    worst = 0.0
    for mid in range(1, 66, 4):
        mv = get_movement(mid)
        tau = model.inverse_dynamics(*mv.evaluate(mv.sample_times(ref.rate_hz)))
        worst = max(worst, float(np.abs(tau - ref.torques(mid, size)).max()))
    assert worst < 1e-9, worst


def test_unknown_keys_are_refused():
    ref = load_reference()
    with pytest.raises(ValueError, match="body size 42"):
        ref.torques(1, 42)
    with pytest.raises(ValueError, match="movement 66"):
        ref.torques(66, 50)
