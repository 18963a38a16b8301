"""The virtual arm's core (forearm_dynamics.simulation): forward dynamics that can fail.

ID∘FD identity, bit-for-bit determinism, energy conservation of RK4, the order of the
solvers, joint limits and damping doing what passive.py documents, and every model kind,
body size, side and payload stepping.
"""

import numpy as np
import pytest

from forearm_dynamics.anthropometry import size_names
from forearm_dynamics.dynamics import build_model
from forearm_dynamics.simulation import (
    DEFAULT_DAMPING,
    ArmSimulator,
    SimSettings,
    joint_bounds,
    limit_gains,
    neutral_posture,
    simulate,
    total_energy,
)

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def arm():
    return build_model("segmented", 50)


def _free(arm, method="rk4", dt=1e-3):
    return ArmSimulator(arm, SimSettings(dt, method, damping=0.0, joint_limits=False))


@pytest.mark.parametrize("kind,size,side,payload", [
    ("segmented", 50, "right", 0.0), ("anatomical", 5, "left", 0.0),
    ("solid", 95, "right", 1.0), ("segmented", "female_5", "left", 0.3)])
def test_inverse_dynamics_of_forward_dynamics_is_identity(kind, size, side, payload):
    arm = build_model(kind, size, side=side, payload_mass=payload)
    rng = np.random.default_rng(7)
    lo, hi = joint_bounds(arm)
    free = _free(arm)
    passive = ArmSimulator(arm, SimSettings(damping=1e-4))
    for _ in range(50):
        q = rng.uniform(lo - 0.3, hi + 0.3)  # beyond the limits too: the limit springs act
        qd = rng.normal(0.0, 2.0, arm.nv)
        tau = rng.normal(0.0, 1.0, arm.nv) * np.abs(arm.gravity_torques(q)).clip(1e-3)
        qdd = free.acceleration(q, qd, tau)
        np.testing.assert_allclose(arm.inverse_dynamics(q, qd, qdd), tau, rtol=0, atol=1e-9)
        qdd = passive.acceleration(q, qd, tau)
        np.testing.assert_allclose(arm.inverse_dynamics(q, qd, qdd),
                                   tau + passive.passive.torque(q, qd), rtol=0, atol=1e-9)


@pytest.mark.parametrize("method", ["rk4", "semi_implicit_euler"])
def test_same_input_same_trajectory_bit_for_bit(method):
    rng = np.random.default_rng(3)
    tau = rng.normal(0.0, 0.02, (400, 20))
    runs = []
    for _ in range(2):
        arm = build_model("segmented", 50, payload_mass=0.2)  # a fresh model and Data each time
        q0 = neutral_posture(arm) + 0.01
        runs.append(simulate(arm, q0, np.zeros(20), tau, method=method, damping=2e-5))
    assert np.array_equal(runs[0].q, runs[1].q) and np.array_equal(runs[0].qd, runs[1].qd)
    assert np.abs(runs[0].q[-1] - runs[0].q[0]).max() > 1e-3  # it moved


def test_rk4_energy_drift_over_two_seconds(arm):
    """No damping, no limits, zero command: the arm falls and tumbles under gravity (fingers
    turn several times); total energy stays within 1e-5 J (measured 2.3e-6 J) while kinetic
    energy reaches > 0.3 J. Semi-implicit Euler at 1 ms is first order: far worse."""
    q0 = neutral_posture(arm)
    r = simulate(arm, q0, np.zeros(20), None, duration=2.0, damping=0.0, joint_limits=False)
    e = np.array([total_energy(arm, q, v) for q, v in zip(r.q, r.qd, strict=True)])
    e_kin = e - np.array([total_energy(arm, q, np.zeros(20)) for q in r.q])
    assert e_kin.max() > 0.3
    assert np.abs(e - e[0]).max() <= 1e-5
    r = simulate(arm, q0, np.zeros(20), None, duration=2.0, method="semi_implicit_euler",
                 damping=0.0, joint_limits=False)
    e_euler = np.array([total_energy(arm, q, v) for q, v in zip(r.q, r.qd, strict=True)])
    assert np.abs(e_euler - e_euler[0]).max() > 100 * np.abs(e - e[0]).max()


def test_damping_dissipates(arm):
    q0 = neutral_posture(arm)
    r = simulate(arm, q0, np.zeros(20), None, duration=1.0, damping=5e-5, joint_limits=False)
    e = np.array([total_energy(arm, q, v) for q, v in zip(r.q, r.qd, strict=True)])
    assert e[-1] < e[0] - 1e-4
    assert np.all(np.diff(e) <= 1e-9)  # never gains energy (beyond RK4's own ~1e-9 J/step)


def test_solver_orders(arm):
    """Halving dt cuts RK4's error ~16x (4th order) and semi-implicit Euler's ~2x."""
    q0 = neutral_posture(arm)
    tau = arm.gravity_torques(q0) * 0.5

    def end(dt, method):
        return simulate(arm, q0, np.zeros(20), lambda t, q, qd: tau * (1.0 + np.sin(10.0 * t)),
                        dt=dt, method=method, duration=0.2, damping=0.0, joint_limits=False).q[-1]

    exact = end(1.25e-4, "rk4")
    e1, e2 = (np.abs(end(dt, "rk4") - exact).max() for dt in (2e-3, 1e-3))
    assert 12.0 < e1 / e2 < 20.0
    f1, f2 = (np.abs(end(dt, "semi_implicit_euler") - exact).max() for dt in (2e-3, 1e-3))
    assert 1.6 < f1 / f2 < 2.5


def test_gravity_torque_holds_the_arm(arm):
    q0 = neutral_posture(arm) + 0.1
    g = arm.gravity_torques(q0)
    r = simulate(arm, q0, np.zeros(20), lambda t, q, qd: g, duration=0.5, damping=0.0,
                 joint_limits=False)
    assert np.abs(r.q - q0).max() < 1e-9


def test_limit_spring_stops_the_elbow(arm):
    """A constant torque pushing the elbow past its upper limit: it settles beyond the limit
    by (torque + gravity) / k, as passive.py documents, and is pushed back once released."""
    k, _ = limit_gains(arm)
    _, hi = joint_bounds(arm)
    q0 = neutral_posture(arm)
    q0[0] = hi[0] - 0.05
    sim = ArmSimulator(arm, SimSettings(damping={"elbow_flexion": 0.05}), q0)  # elbow damping: settles in 1 s
    tau = np.zeros(20)
    tau[0] = 5.0
    g = arm.gravity_torques
    for _ in range(1500):
        # the hand's joints held by their gravity torques: only the elbow moves
        tau[1:] = g(sim.q)[1:]
        sim.step(tau)
    pen = sim.q[0] - hi[0]
    static = (tau[0] - g(sim.q)[0]) / k[0]
    assert pen > 0 and abs(pen - static) < 0.05 * static, (pen, static)
    for _ in range(300):
        sim.step(np.r_[0.0, g(sim.q)[1:]])
    assert sim.q[0] < hi[0] + 1e-3


@pytest.mark.parametrize("method", ["rk4", "semi_implicit_euler"])
@pytest.mark.parametrize("size", [5, "female_5", 95])
def test_limits_stable_with_every_joint_pushed_out(method, size):
    """Every joint driven past its limit at once by 3x its gravity torque (a stress test of
    the limit springs' stability on the smallest and largest arms; with damping ratio 0.7
    instead of 0.3 RK4 blew up here): the arm stays in a bounded state."""
    arm = build_model("segmented", size)
    _, hi = joint_bounds(arm)
    tau = 3.0 * np.abs(arm.gravity_torques(neutral_posture(arm))).clip(1e-4)
    r = simulate(arm, neutral_posture(arm), np.zeros(20), np.tile(tau, (1000, 1)), method=method)
    assert np.isfinite(r.q).all()
    k, _ = limit_gains(arm)
    # settles where the spring balances the push (plus gravity and coupling)
    assert np.all(r.q[-1] - hi < 3.0 * (tau + np.abs(arm.gravity_torques(r.q[-1]))) / k + 1e-6)
    assert np.abs(r.qd[-1]).max() < 10.0  # damped, still ringing (the thumb CMC: ~3 rad/s)


def test_damping_beyond_the_solver_stability_is_refused(arm):
    with pytest.raises(ValueError, match=r"damping too large for rk4 .* stiffest joint is \w+_dip"):
        ArmSimulator(arm, SimSettings(damping=1e-2))
    ArmSimulator(arm, SimSettings(damping={"*": DEFAULT_DAMPING, "elbow_flexion": 1.0}))


@pytest.mark.parametrize("kind", ["segmented", "solid", "anatomical"])
@pytest.mark.parametrize("size", [5, 50, 95, *[n for n in size_names() if n.startswith("female")]])
def test_every_model_kind_and_size_steps(kind, size):
    for side, payload in (("right", 0.0), ("left", 0.5)):
        arm = build_model(kind, size, side=side, payload_mass=payload)
        r = simulate(arm, None, None, None, steps=200)
        assert np.isfinite(r.q).all() and np.abs(r.q[-1] - r.q[0]).max() > 1e-4


def test_left_arm_mirrors_the_right():
    """Same joint names and signs for the left arm: the same commands give the same angles."""
    right, left = build_model("segmented", 50), build_model("segmented", 50, side="left")
    tau = np.random.default_rng(0).normal(0.0, 0.01, (300, 20))
    a = simulate(right, None, None, tau)
    b = simulate(left, None, None, tau)
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-9)


def test_payload_pulls_the_hand_down():
    q0 = None
    light = simulate(build_model("segmented", 50), q0, None, None, steps=200, joint_limits=False)
    heavy = simulate(build_model("segmented", 50, payload_mass=2.0), q0, None, None, steps=200,
                     joint_limits=False)
    assert abs(heavy.q[-1, 0] - light.q[-1, 0]) > 1e-3


def test_array_commands_equal_stepping_by_hand(arm):
    tau = np.random.default_rng(1).normal(0.0, 0.01, (100, 20))
    r = simulate(arm, None, None, tau)
    sim = ArmSimulator(arm)
    for row in tau:
        sim.step(row)
    assert np.array_equal(sim.q, r.q[-1]) and sim.t == pytest.approx(0.1)


@pytest.mark.parametrize("call,match", [
    (lambda a: simulate(a, np.zeros(19), None, None, steps=1), "q0 must be 20 finite"),
    (lambda a: simulate(a, np.full(20, np.nan), None, None, steps=1), "q0 must be 20 finite"),
    (lambda a: simulate(a, None, None, None, steps=1, method="rk45"), "method must be one of"),
    (lambda a: simulate(a, None, None, None), "give duration or steps"),
    (lambda a: simulate(a, None, None, np.zeros((3, 20)), steps=5), "3 rows for 5 steps"),
    (lambda a: ArmSimulator(a, SimSettings(damping={"elbow": 1.0})), "unknown joint"),
    (lambda a: ArmSimulator(a, SimSettings(damping=-1.0)), "finite and >= 0"),
    (lambda a: SimSettings(dt=0.0), "dt must be"),
])
def test_bad_input_is_one_clear_error(arm, call, match):
    with pytest.raises(ValueError, match=match):
        call(arm)
