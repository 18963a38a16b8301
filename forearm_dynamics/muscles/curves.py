"""DeGroote-Fregly 2016 muscle curves, rigid tendon: what a unit activation can pull.

Why these curves: they are smooth, published in closed form (De Groote F, Kinney AL, Rao AV,
Fregly BJ 2016, Ann Biomed Eng 44(10):2922-2936, doi:10.1007/s10439-016-1591-9, Supplementary
"Muscle Model" with the constants below), and they are OpenSim's DeGrooteFregly2016Muscle,
the class whose optimal force OpenSim's StaticOptimization computes correctly, so the SO here
and OpenSim's use the same muscle (issue 31 item 5).

Normalised fibre length l̃ = l_f / L0, normalised fibre velocity ṽ = v_f / (vmax·L0)
(positive = lengthening; ṽ = −1 is the maximum shortening velocity, force 0).
"""

from __future__ import annotations

import numpy as np

# Active force-length: sum of three Gaussian-like curves (b1i, b2i, b3i, b4i).
_B1 = np.array([0.8150671134243542, 0.433004984392647, 0.1])
_B2 = np.array([1.055033428970575, 0.716775413397760, 1.0])
_B3 = np.array([0.162384573599574, -0.029947116970696, 0.353553390593274])
_B4 = np.array([0.063303448465465, 0.200356847296188, 0.0])
# Force-velocity.
_D1, _D2, _D3, _D4 = -0.3211346127989808, -8.149, -0.374, 0.8825327733249912
# Passive force-length: strain at one normalised force e0, shape kPE; zero at l̃ = 0.2.
_KPE, _E0, _LMIN = 4.0, 0.6, 0.2


def active_force_length(l_norm: np.ndarray) -> np.ndarray:
    """f_L(l̃), 1 at l̃ ≈ 1."""
    ln = np.asarray(l_norm, float)[..., None]
    return np.sum(_B1 * np.exp(-0.5 * (ln - _B2) ** 2 / (_B3 + _B4 * ln) ** 2), axis=-1)


def force_velocity(v_norm: np.ndarray) -> np.ndarray:
    """f_V(ṽ): 1 at rest, 0 at ṽ = −1, ~1.8 when lengthening fast."""
    x = _D2 * np.asarray(v_norm, float) + _D3
    return _D1 * np.arcsinh(x) + _D4  # the paper's log(x + sqrt(x² + 1))


def passive_force_length(l_norm: np.ndarray) -> np.ndarray:
    """f_PE(l̃): 0 below l̃ = 0.2, 1 at l̃ = 1 + e0 (OpenSim's DeGrooteFregly2016 form)."""
    ln = np.asarray(l_norm, float)
    num = np.exp(_KPE * (ln - 1.0) / _E0) - np.exp(_KPE * (_LMIN - 1.0) / _E0)
    den = np.exp(_KPE) - np.exp(_KPE * (_LMIN - 1.0) / _E0)
    return np.maximum(num / den, 0.0)


def fibre_state(length, velocity, l0, lts, alpha0):
    """Rigid tendon: fibre length, cos(pennation), fibre velocity from the path's.

    Constant-thickness pennation: l_f sin(alpha) = L0 sin(alpha0).
    """
    h = l0 * np.sin(alpha0)
    lm = np.maximum(length - lts, 1e-6)
    lf = np.sqrt(h * h + lm * lm)
    cos_a = lm / lf
    return lf, cos_a, velocity * cos_a


class UnitForces:
    """unit_forces for one model with its constants precomputed: the per-sample hot path.

    Same numbers as unit_forces to rounding on the rigid, non-pennate path (rtol 1e-12,
    test_muscles checks): the same curves with constants folded (F0 into the force-velocity's,
    arcsinh for its log form), written into arrays made once here (each numpy call costs
    microseconds in a node that sleeps between samples; an allocation more). The arrays
    returned are those buffers: read them before the next call."""

    def __init__(self, model_params, *, use_velocity: bool = True, passive: bool = False):
        f0, l0, lts, alpha0, vmax = (np.asarray(p, float) for p in model_params)
        self.params = (f0, l0, lts, alpha0, vmax)
        self.f0, self.lts, self.inv_l0 = f0, lts, 1.0 / l0
        self.h2 = (l0 * np.sin(alpha0)) ** 2
        self.pennate = bool(np.any(alpha0 != 0))
        self.v_scale = _D2 / (vmax * l0)
        # F0 folded into the force-velocity's constants: F0·fL·(d1·asinh + d4) = fL·(F0d1·asinh
        # + F0d4), one product fewer a sample (equal to the curves to rounding, rtol 1e-12)
        self.f0_d1, self.f0_d4 = f0 * _D1, f0 * _D4
        self.use_velocity, self.passive = use_velocity, passive
        n = len(f0)
        self._ln, self._fl, self._fv, self._unit = (np.empty(n) for _ in range(4))
        self._g, self._d = np.empty((n, 3)), np.empty((n, 3))
        self._zeros = np.zeros(n)

    def __call__(self, length, velocity):
        if self.pennate or self.passive:
            return unit_forces(self.params, length, velocity, use_velocity=self.use_velocity,
                               passive=self.passive)
        # ln = max(length - lts, 1e-6) / L0;  fl = exp(-0.5 ((ln - b2) / (b3 + b4 ln))²) · b1
        ln, g, d, fl = self._ln, self._g, self._d, self._fl
        np.subtract(length, self.lts, out=ln)
        np.maximum(ln, 1e-6, out=ln)
        np.multiply(ln, self.inv_l0, out=ln)
        lc = ln[:, None]
        np.subtract(lc, _B2, out=g)
        np.multiply(_B4, lc, out=d)
        np.add(_B3, d, out=d)
        np.divide(g, d, out=g)
        np.square(g, out=g)
        np.multiply(-0.5, g, out=g)
        np.exp(g, out=g)
        np.matmul(g, _B1, out=fl)
        if not self.use_velocity:
            return np.multiply(self.f0, fl, out=self._unit), self._zeros
        # unit = fl · (F0·d1 asinh(v_scale v + d3) + F0·d4)
        fv = self._fv
        np.multiply(self.v_scale, velocity, out=fv)
        np.add(fv, _D3, out=fv)
        np.arcsinh(fv, out=fv)
        np.multiply(self.f0_d1, fv, out=fv)
        np.add(fv, self.f0_d4, out=fv)
        return np.multiply(fl, fv, out=self._unit), self._zeros


def unit_forces(model_params, length, velocity, *, use_velocity: bool = True,
                passive: bool = False):
    """Tendon force per unit activation, and the passive tendon force (N), per muscle.

    model_params: (F0, L0, LTs, alpha0, vmax) arrays (n,). length, velocity: (..., n).
    """
    f0, l0, lts, alpha0, vmax = model_params
    lf, cos_a, vf = fibre_state(length, velocity, l0, lts, alpha0)
    ln = lf / l0
    fv = force_velocity(vf / (vmax * l0)) if use_velocity else 1.0
    active = f0 * active_force_length(ln) * fv * cos_a
    pas = f0 * passive_force_length(ln) * cos_a if passive else np.zeros_like(active)
    return active, pas
