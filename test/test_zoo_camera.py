"""The simulated 30 Hz camera row of the sensor zoo, run here on its own: the default
`kalman` is no worse than the causal 6 Hz Butterworth on any DOF group.

Why a test: from commit 8f13e4e to this one the row was 0.138 (fingers) against the
baseline's 0.089, every group worse, and nobody saw it because the zoo's committed output
was not re-run. The cause: the jump gate armed by the third difference before the 10 Hz
noise estimate, which at 30 Hz measures the movement, not the noise
(noise_belief.WHITE_ARM_MAX_PERIOD_S). Same streams, seed and score as
benchmarks/estimation_zoo.py (every 4th movement)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def test_camera_30hz_kalman_no_worse_than_the_baseline() -> None:
    import estimation_zoo as zoo
    import sensors

    from forearm_dynamics.description import JOINT_NAMES
    from forearm_dynamics.dynamics import build_model
    from forearm_dynamics.movements import movement_library

    arm = build_model("segmented")
    ptp = zoo.library_ptp(arm)
    index, sensor = next((i, s) for i, s in enumerate(sensors.zoo()) if s.name == "camera_30hz")
    srun = zoo.SensorRun(arm, sensor, movement_library()[::4], zoo.SEED + index)
    scores = {}
    for label, name, settings in (("kalman", "kalman", {}),
                                  ("baseline", "butterworth", {"butterworth_cutoff_hz": 6.0})):
        outs, _ = zoo.run(lambda name=name, settings=settings: zoo.build(name, settings,
                                                                         len(JOINT_NAMES)), srun)
        scores[label] = zoo.score(arm, srun, outs, ptp)
    worse = {g: (round(k, 4), round(scores["baseline"][g], 4)) for g, k in scores["kalman"].items()
             if k > scores["baseline"][g]}
    assert not worse, f"kalman worse than the 6 Hz Butterworth on the 30 Hz camera: {worse}"
