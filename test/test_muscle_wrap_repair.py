"""wrap_repair's rule on a synthetic source, without MuJoCo (issue 31 item 2: "find and repair
or exclude path-wrapping artefacts").

Three muscles about joint 0, whose source limits are ±1 rad (our range goes to ±1.4):
- muscle 0 jumps past the limit: at q0 < -1.2 its path is 6 mm longer and its moment arm
  turns from +10 to -15 mm (MyoArm's FDS2 past -65° of wrist extension, in kind);
- muscle 1 changes steeply but continuously past the other limit (+17 to -18 mm within a
  degree near q0 = 1.18; MyoArm's FCU does it over ~20° past 45° of flexion): unexplained
  over the coarse 5° step, explained over 0.1°;
- muscle 2 jumps inside the limits (q0 = 0.5: RI2 at index MCP 9°, in kind).
The rule must repair muscle 0 from its jump on (moment arm held at its clean value, length
continued) and leave muscles 1 and 2, and every posture inside the limits, as they are.
"""

from __future__ import annotations

import numpy as np
import pytest

from forearm_dynamics.muscles.wrap_repair import repair

pytestmark = pytest.mark.unit

TOL = 5e-4  # fit.JUMP_TOL
LO, HI = np.full(20, -1.0), np.full(20, 1.0)


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


class Source:
    """evaluate(q (N, 20)) -> lengths (N, 3), moment arms (N, 3, 20), as fit.MyoArm."""

    def __init__(self):
        self.asked = 0

    def evaluate(self, q):
        q = np.atleast_2d(q)
        self.asked += len(q)
        x = q[:, 0]
        L, R = np.zeros((len(q), 3)), np.zeros((len(q), 3, 20))
        jumped = x < -1.2
        R[:, 0, 0] = np.where(jumped, -0.015, 0.010)
        L[:, 0] = np.where(jumped, 0.3 + 0.006 - 0.010 * -1.2 + 0.015 * (x + 1.2), 0.3 - 0.010 * x)
        w = 0.005  # rad: a sigmoid 0.3° wide; length = -integral of the moment arm
        R[:, 1, 0] = 0.017 - 0.035 * _sigmoid((x - 1.18) / w)
        L[:, 1] = 0.25 - 0.017 * x + 0.035 * w * np.logaddexp(0.0, (x - 1.18) / w)
        inside_jump = x > 0.5
        R[:, 2, 0] = np.where(inside_jump, 0.005, -0.005)
        L[:, 2] = 0.1 + 0.005 * x + np.where(inside_jump, 0.004 - 0.01 * x + 0.005, 0.0)
        return L, R


def test_a_jump_past_the_limit_is_repaired_and_nothing_else():
    src = Source()
    x = np.array([-1.4, -1.3, -1.21, -1.19, -1.1, -0.5, 0.45, 0.55, 1.1, 1.19, 1.25, 1.4])
    q = np.zeros((len(x), 20))
    q[:, 0] = x
    q[:, 3] = 0.2  # a joint the muscles do not cross, inside its limits
    L, R = src.evaluate(q)
    L2, R2, mask, info = repair(src, q, L, R, LO, HI, TOL)
    jumped = x < -1.2
    assert (mask[:, 0] == jumped).all(), mask[:, 0]
    assert not mask[:, 1:].any(), mask  # the steep continuous change and the inside jump stay
    np.testing.assert_array_equal(L2[:, 1:], L[:, 1:])
    np.testing.assert_array_equal(R2[~jumped], R[~jumped])
    # from the jump on: the clean branch's moment arm, the clean branch's length continued
    np.testing.assert_allclose(R2[jumped, 0, 0], 0.010, atol=1e-12)
    np.testing.assert_allclose(L2[jumped, 0], 0.3 - 0.010 * x[jumped], atol=1e-9)
    assert info["evaluated"] == src.asked - len(q)  # every posture it asked the source for


def test_inside_the_limits_nothing_is_asked_or_changed():
    src = Source()
    q = np.random.default_rng(1).uniform(-1.0, 1.0, size=(50, 20))
    L, R = src.evaluate(q)
    L2, R2, mask, info = repair(src, q, L, R, LO, HI, TOL)
    assert not mask.any() and info["evaluated"] == 0
    np.testing.assert_array_equal(L2, L)
    np.testing.assert_array_equal(R2, R)
