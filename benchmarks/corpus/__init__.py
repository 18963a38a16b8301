"""The real-recording corpus (issue 29): raw recordings of arm movements, split by subject
or source into a tuning half and a held-out half (split.yaml, fixed before any tuning).

    from benchmarks.corpus import load
    recs = load("tuning")                       # committed UE-ADL angles of the tuning subjects
    recs = load("tuning", opensim_models=DIR)   # + Hamner running (fetched, not committed)

Each `CorpusRecording` holds stamps (ns, from 1 s) and positions (N, 20) rad in the
model's joint order (description.JOINT_NAMES): the joints it measures (elbow_flexion,
pro_sup, and for UE-ADL wrist_flexion and wrist_deviation) and the others held at 0 (as
mot_to_bag holds what a file does not give). README.md says where each comes from.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from forearm_dynamics.description import JOINT_NAMES

HERE = Path(__file__).resolve().parent
HALVES = ("tuning", "held_out")
#: joints of the derived angle arrays (their column order)
UE_JOINTS = ("elbow_flexion", "pro_sup", "wrist_flexion", "wrist_deviation")
#: OpenSim running IK results: (split source, path, commit); read with git show
OPENSIM = {
    "opensim_hamner": ("Pipelines/Hamner/outputReference/ResultsIK/subject02_running_ik.mot",
                       "025471aeb655259d7442d87110a5189cf6ffe3df"),
    "opensim_rajagopal": ("Pipelines/Rajagopal/outputReference/ResultsIK/subject01_run_IK.mot",
                          "24edd5723b90c71ff0affd55e995b5bdd7271058"),
}
OPENSIM_MAP = {"elbow_flex_r": "elbow_flexion", "pro_sup_r": "pro_sup", "wrist_flex_r": "wrist_flexion",
               "wrist_dev_r": "wrist_deviation"}


@dataclass
class CorpusRecording:
    name: str
    source: str
    subject: str
    task: str
    side: str  # "right" / "left" (the model's side to compute with)
    rate_hz: float
    stamps_ns: np.ndarray  # (N,) int64
    q: np.ndarray  # (N, 20) rad
    measured: tuple[str, ...]
    meta: dict

    @property
    def columns(self) -> list[int]:
        return [JOINT_NAMES.index(j) for j in self.measured]


def split() -> dict:
    with open(HERE / "split.yaml", encoding="utf-8") as fh:
        return yaml.safe_load(fh)


def half_of(source: str, subject: str) -> str | None:
    sp = split()
    for h in HALVES:
        if source == "ue_adl" and subject in sp[h].get("ue_adl", []):
            return h
        if source != "ue_adl" and source in sp[h].get("sources", []):
            return h
    return None


def _full(q4: np.ndarray, joints) -> np.ndarray:
    q = np.zeros((q4.shape[0], len(JOINT_NAMES)))
    for k, j in enumerate(joints):
        q[:, JOINT_NAMES.index(j)] = q4[:, k]
    return q


def _ue_adl(half: str) -> list[CorpusRecording]:
    manifest = json.loads((HERE / "manifest.json").read_text(encoding="utf-8"))
    data = np.load(HERE / "ue_adl.npz")
    out = []
    for m in manifest["recordings"]:
        if m["source"] != "ue_adl" or half_of("ue_adl", m["subject"]) != half:
            continue
        q4 = data[f"{m['name']}/q"]
        stamps = 1_000_000_000 + np.round(np.arange(len(q4)) / m["rate_hz"] * 1e9).astype(np.int64)
        out.append(CorpusRecording(m["name"], "ue_adl", m["subject"], m["task"], m["side"], m["rate_hz"],
                                   stamps, _full(q4, UE_JOINTS), UE_JOINTS, m))
    return out


def read_opensim_mot(text: str) -> tuple[list[str], np.ndarray, bool]:
    lines = text.splitlines()
    end = next(i for i, ln in enumerate(lines) if ln.strip().lower() == "endheader")
    degrees = any(ln.strip().lower() == "indegrees=yes" for ln in lines[:end])
    cols = lines[end + 1].split()
    data = np.array([[float(x) for x in ln.split()] for ln in lines[end + 2:] if ln.strip()])
    return cols, data, degrees


def _opensim(half: str, repo: Path) -> list[CorpusRecording]:
    import subprocess

    out = []
    for source, (path, commit) in OPENSIM.items():
        if half_of(source, "") != half:
            continue
        text = subprocess.run(["git", "-C", str(repo), "show", f"{commit}:{path}"],  # noqa: S607
                              capture_output=True, check=True, text=True).stdout
        cols, data, degrees = read_opensim_mot(text)
        t = data[:, 0]
        joints = [j for c, j in OPENSIM_MAP.items() if c in cols and np.ptp(data[:, cols.index(c)]) > 0]
        q4 = np.stack([data[:, cols.index(c)] for c, j in OPENSIM_MAP.items() if j in joints], axis=1)
        q4 = np.radians(q4) if degrees else q4
        rate = 1.0 / float(np.median(np.diff(t)))
        stamps = 1_000_000_000 + np.round((t - t[0]) * 1e9).astype(np.int64)
        meta = {"name": source, "source": source, "file": path, "commit": commit,
                "repository": "github.com/opensim-org/opensim-models",
                "licence": "no licence statement in the repository: fetched, never committed",
                "task": "running (arm swing)"}
        out.append(CorpusRecording(source, source, source, "running (arm swing)", "right", rate, stamps,
                                   _full(q4, joints), tuple(joints), meta))
    return out


def load(half: str, opensim_models: Path | None = None) -> list[CorpusRecording]:
    """The recordings of one half ("tuning" or "held_out"), sorted by name; with
    `opensim_models` (a checkout or mirror of opensim-org/opensim-models) also its running
    trials of that half."""
    if half not in HALVES:
        raise ValueError(f"half must be one of {HALVES}, got {half!r}")
    recs = _ue_adl(half)
    if opensim_models is not None:
        recs += _opensim(half, Path(opensim_models))
    return sorted(recs, key=lambda r: r.name)
