"""Gold-standard reference torques: the anatomical model in OpenSim, shipped as package data.

File format (`forearm_dynamics/data/reference_torques.npz`, a NumPy .npz, deflate-compressed):
  torques_code  (8, K) uint8    the torques, encoded (below); decode with load_reference()
  shape         (4,)            (S, 65, N, 20): S body sizes x 65 movements x N samples x 20
  body_sizes    (S,)            percentiles, e.g. [5, 50, 95]
  movement_ids  (65,)           1..65
  rate_hz       ()              sampling rate; sample k is at t = k / rate_hz from the start
  joint_names   (20,)           column order (= forearm_dynamics.JOINT_NAMES)
  meta          ()              JSON: engine and version, model kind, generator command
Raw inverse dynamics (unfiltered); filter with filtering.lowpass as the paper did.

Encoding (3x smaller than float64, exact to 5e-13 N·m): torques rounded to integer
pico-newton-metres (int64), second differences along time (the torques are smooth, so these
are small), then byte-shuffled (byte j of every value together) so deflate finds the zeros.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from .description import JOINT_NAMES

REFERENCE_FILE = Path(__file__).resolve().parent / "data" / "reference_torques.npz"
QUANTUM_NM = 1e-12


def encode_torques(torques: np.ndarray) -> np.ndarray:
    q = np.round(np.asarray(torques, np.float64) / QUANTUM_NM).astype(np.int64)
    d2 = np.diff(np.diff(q, axis=2, prepend=0), axis=2, prepend=0)
    return np.ascontiguousarray(d2.reshape(-1).view(np.uint8).reshape(-1, 8).T)


def decode_torques(code: np.ndarray, shape) -> np.ndarray:
    d2 = np.ascontiguousarray(code.T).view(np.int64).reshape(tuple(int(s) for s in shape))
    return np.cumsum(np.cumsum(d2, axis=2), axis=2) * QUANTUM_NM


@dataclass(frozen=True)
class ReferenceTorques:
    torques_all: np.ndarray  # (S, 65, N, 20)
    body_sizes: tuple[int, ...]
    movement_ids: tuple[int, ...]
    rate_hz: float
    joint_names: tuple[str, ...]
    meta: dict

    @property
    def times(self) -> np.ndarray:
        return np.arange(self.torques_all.shape[2]) / self.rate_hz

    def torques(self, movement_id: int, body_size: int = 50) -> np.ndarray:
        """(N, 20) raw reference torques of one movement at one body size."""
        if body_size not in self.body_sizes:
            raise ValueError(f"no reference for body size {body_size!r}; have {self.body_sizes}")
        if movement_id not in self.movement_ids:
            raise ValueError(f"no reference for movement {movement_id!r}")
        return self.torques_all[self.body_sizes.index(body_size), self.movement_ids.index(movement_id)]


def save_reference(path: Path, torques: np.ndarray, body_sizes, movement_ids, rate_hz: float,
                   meta: dict) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(
        tmp, torques_code=encode_torques(torques), shape=np.asarray(np.shape(torques), np.int64),
        body_sizes=np.asarray(body_sizes, np.int64),
        movement_ids=np.asarray(movement_ids, np.int64), rate_hz=np.float64(rate_hz),
        joint_names=np.array(JOINT_NAMES), meta=np.array(json.dumps(meta, sort_keys=True)),
    )
    tmp.replace(path)  # atomic: a reader never sees a half-written file


def read_reference(path: Path) -> ReferenceTorques:
    with np.load(path, allow_pickle=False) as z:
        names = tuple(str(n) for n in z["joint_names"])
        if names != JOINT_NAMES:
            raise ValueError(f"{path}: joint order {names} differs from JOINT_NAMES")
        return ReferenceTorques(
            torques_all=decode_torques(z["torques_code"], z["shape"]),
            body_sizes=tuple(int(b) for b in z["body_sizes"]),
            movement_ids=tuple(int(m) for m in z["movement_ids"]), rate_hz=float(z["rate_hz"]),
            joint_names=names, meta=json.loads(str(z["meta"])),
        )


@lru_cache(maxsize=1)
def load_reference() -> ReferenceTorques:
    """The shipped gold-standard torques (regenerate with `make reference`)."""
    if not REFERENCE_FILE.is_file():
        raise FileNotFoundError(f"{REFERENCE_FILE} is missing; run `make reference`")
    return read_reference(REFERENCE_FILE)
