"""The muscle layer's per-sample shortcuts, each against the plain computation it replaces.

- Surrogate.evaluate into new_outputs() (the sparse product writing R and L in place, rows
  re-laid [L; R flat]) equals the scatter-and-copy path into arrays of the caller's own and
  the allocating path, bit for bit (the same rows, the same term order), unspanned R stays 0;
- the reserves as daqp soft constraints (weight r_opt²/2): the optimum of min Σa² + Σ(r/r_opt)²
  s.t. R·F(a) + r = τ, 0 ≤ a ≤ 1 for per-joint r_opt from 0.3 to 3 N·m, against scipy's bounded
  least squares (BVLS, tol 1e-12) on the reserve-eliminated problem
  min |a|² + |diag(1/r_opt)(τ − A a)|²: 1e-5 in every activation and reserve (N·m), as
  test_muscles' unit-weight comparison; torques scaled ×3 so the reserves carry some.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from forearm_dynamics import build_model, movement_library
from forearm_dynamics.muscles import StaticOptimizer
from forearm_dynamics.muscles.curves import unit_forces

pytestmark = pytest.mark.unit


def test_in_place_outputs_equal_the_scatter_and_the_allocating_paths(mm):
    s = mm.surrogate
    own = s.new_outputs()
    foreign = (np.full_like(own[0], 0.0), np.full_like(own[1], 7.0))
    rng = np.random.default_rng(17)
    spanned = np.zeros_like(own[0], bool)
    spanned[s.pair_rows, s.pair_cols] = True
    for q in s.center + s.half * rng.uniform(-1.2, 1.2, size=(40, 20)):
        R, L = s.evaluate(q, own)
        assert R is own[0] and L is own[1]
        Rf, Lf = s.evaluate(q, foreign)
        Ra, La = s.evaluate(q)
        for x, y, z in ((R, Rf, Ra), (L, Lf, La)):
            assert np.array_equal(x, y) and np.array_equal(x, z)
        assert np.all(R[~spanned] == 0.0) and np.any(R[spanned] != 0.0)


def test_soft_reserves_with_per_joint_weights_agree_with_bvls(mm):
    arm = build_model("segmented")
    r_opt = np.linspace(0.3, 3.0, 20)
    mv = movement_library()[40]
    q, qd, qdd = mv.evaluate(mv.sample_times(50))
    tau = 3.0 * arm.inverse_dynamics(q, qd, qdd)
    so = StaticOptimizer(mm, reserve_optimal_torque=r_opt)
    used = 0.0
    for k in range(0, len(q), 5):
        s = so.solve(q[k], qd[k], tau[k])
        R, L, V = mm.geometry(q[k], qd[k])
        unit, _ = unit_forces(mm.params(), L, V)
        A = (R * unit[:, None]).T
        ref = lsq_linear(np.vstack([np.eye(mm.n), A / r_opt[:, None]]),
                         np.r_[np.zeros(mm.n), tau[k] / r_opt], bounds=(0, 1), method="bvls",
                         tol=1e-12)
        assert ref.success
        np.testing.assert_allclose(s.activations, ref.x, atol=1e-5)
        np.testing.assert_allclose(s.reserves, tau[k] - A @ ref.x, atol=1e-5)
        assert s.residual <= 1e-9
        used = max(used, float(np.abs(s.reserves).max()))
    assert used > 1e-3  # the weights were exercised: some reserve carried torque
