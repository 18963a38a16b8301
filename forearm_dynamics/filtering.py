"""Zero-phase Butterworth low-pass, as the paper filtered its torques (6 Hz)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import yaml
from scipy.signal import butter, sosfiltfilt

from .paths import config_file


@lru_cache(maxsize=1)
def analysis_config() -> dict:
    with open(config_file("analysis.yaml"), encoding="utf-8") as fh:
        return yaml.safe_load(fh)


@lru_cache(maxsize=16)
def _sos(cutoff_hz: float, order: int, fs: float) -> np.ndarray:
    return butter(order, cutoff_hz, btype="low", fs=fs, output="sos")


def lowpass(x: np.ndarray, fs: float, cutoff_hz: float | None = None, order: int | None = None,
            axis: int = 0) -> np.ndarray:
    """Forward-backward Butterworth along `axis`; pads with the edge value (the holds are flat)."""
    cfg = analysis_config()["filter"]
    cutoff_hz = float(cfg["cutoff_hz"] if cutoff_hz is None else cutoff_hz)
    order = int(cfg["order"] if order is None else order)
    if not 0 < cutoff_hz < fs / 2:
        raise ValueError(f"cutoff {cutoff_hz} Hz must be in (0, fs/2 = {fs / 2}) Hz")
    x = np.asarray(x, dtype=float)
    n = x.shape[axis]
    return sosfiltfilt(_sos(cutoff_hz, order, float(fs)), x, axis=axis, padtype="constant",
                       padlen=min(n - 1, 3 * (2 * len(_sos(cutoff_hz, order, float(fs))) + 1)))


#: The highest zero-phase cutoff used on a recording, as a fraction of its sample rate
#: (0.8 x Nyquist): above it the filter does nothing useful and scipy's design nears its limit.
MAX_CUTOFF_FRACTION = 0.4


def usable_cutoff(fs: float, cutoff_hz: float | None = None) -> tuple[float, str | None]:
    """(cutoff, note): the cutoff to low-pass a recording sampled at fs with.

    Asked for (cutoff_hz given): that cutoff, ValueError (one line) if it is not below fs/2.
    Not asked for: the practice's (config/analysis.yaml, 6 Hz) when below
    MAX_CUTOFF_FRACTION x fs, else MAX_CUTOFF_FRACTION x fs, with a note that says so (a
    10 Hz recording: 4 Hz; the practice's 6 Hz is above its 5 Hz Nyquist frequency)."""
    if cutoff_hz is not None:
        if not 0 < cutoff_hz < fs / 2:
            raise ValueError(f"cutoff {cutoff_hz:g} Hz must be in (0, {fs / 2:.4g}) Hz: half the "
                             f"recording's {fs:.4g} Hz sample rate")
        return float(cutoff_hz), None
    practice = float(analysis_config()["filter"]["cutoff_hz"])
    top = MAX_CUTOFF_FRACTION * fs
    if practice <= top:
        return practice, None
    return top, (f"the practice's {practice:g} Hz cutoff is above {MAX_CUTOFF_FRACTION:g} x this "
                 f"recording's {fs:.3g} Hz sample rate: low-passed at {top:.3g} Hz instead "
                 "(--cutoff chooses)")
