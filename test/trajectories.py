"""Random smooth trajectories with analytic derivatives, for tests."""

import numpy as np

from forearm_dynamics import build_model


def sine_trajectory(n: int = 200, seed: int = 0, duration: float = 1.0, kind: str = "anatomical"):
    """Sums of sines inside each joint's range: t, q, qd, qdd (N, 20)."""
    rng = np.random.default_rng(seed)
    model = build_model(kind)
    lo = model.model.lowerPositionLimit
    hi = model.model.upperPositionLimit
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    t = np.linspace(0.0, duration, n)
    amp = rng.uniform(0.1, 0.45, (3, 20)) * half
    freq = rng.uniform(0.3, 2.5, (3, 20)) * 2 * np.pi
    phase = rng.uniform(0, 2 * np.pi, (3, 20))
    arg = t[:, None, None] * freq + phase
    q = mid + (amp * np.sin(arg)).sum(axis=1)
    qd = (amp * freq * np.cos(arg)).sum(axis=1)
    qdd = (-amp * freq**2 * np.sin(arg)).sum(axis=1)
    return t, q, qd, qdd
