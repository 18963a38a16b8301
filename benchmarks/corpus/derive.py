"""Derive the real-recording corpus's joint angles from fetched public checkouts.

    .venv/bin/python benchmarks/corpus/derive.py --ue-adl DIR [--out benchmarks/corpus]

Nothing fetched is committed: this script reads the checkouts and writes only the angles it
derives (benchmarks/corpus/<source>.npz) and a manifest (benchmarks/corpus/manifest.json:
per recording source, licence, commit, what was derived, the rawness check).

UE-ADL (GitHub MiaH-kin/UE_ADLdatabase, MIT): Vicon 100 Hz raw marker trajectories (the
`ADLnnnXSr.csv` files; NOT the `...angles.csv`, which its authors cropped and low-passed at
10 Hz). Subjects ADL001 and ADL005 are held out by the reviewer: refused here, never read.
Per subject the static trial places the anatomical landmarks (greater tubercle GTH, lateral
and medial epicondyles LEP/MEP, radial and ulnar styloids SPR/SPU, index base FB) in the
technical clusters (upper arm UAR1-4, forearm LAR1-4, hand HAN1-4): in each frame of a
trial a least-squares rigid fit (Kabsch; every visible cluster marker, >= 3) carries them.
No temporal filter, no gap filling: a frame with a cluster of < 3 markers ends the usable
run; the longest complete run is kept (its frames are listed).

Frames (ISB, Wu et al. 2005; the left arm mirrored x -> -x first, so one set of formulas):
- humerus: y from the epicondyle midpoint to GTH (GTH stands in for the glenohumeral
  centre: it lies on the humeral head, ~2 cm lateral), x normal to the plane (GTH, LEP,
  MEP) forward, z lateral;
- forearm: y from the ulnar styloid to the epicondyle midpoint, x normal to the plane
  (SPU, SPR, epicondyle midpoint) forward, z lateral (radial at supination);
- hand: y from FB to the styloid midpoint, z along SPU -> SPR in the static trial (the
  hand's own axial rotation taken as the forearm's there), carried by the hand cluster;
- thorax (approximate: the marker set has the sternum only): y vertical (lab z), z from
  the other shoulder cluster's centroid to this one's, x = y x z forward.
Angles (our conventions, README table): elbow flexion = ISB elbow JCS alpha (Z of the
humerus, intrinsic Z-X-Y), pro_sup = ISB gamma - 90 deg (ISB 0 = full supination; ours 0 =
hand in the sagittal plane, pronation positive), wrist flexion / ulnar deviation =
intrinsic Z-X-Y of hand in forearm (flexion toward the palm and ulnar deviation positive).
Shoulder (for issue 30): humerus in the approximate thorax frame, ISB Y-X-Y (plane of
elevation, elevation (ISB sign: negative = arm raised), axial rotation), radians.

"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import shutil
import subprocess
from pathlib import Path
from typing import ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from forearm_dynamics.offline.realscore import rawness

HERE = Path(__file__).resolve().parent
ANGLES = ("elbow_flexion", "pro_sup", "wrist_flexion", "wrist_deviation")
SHOULDER = ("shoulder_plane", "shoulder_elevation", "shoulder_rotation")
#: held out by the reviewer: never read, not even for a look
FORBIDDEN = ("ADL001", "ADL005")
GIT = shutil.which("git") or "git"
UE_TASKS = {"F": "reach forward", "A": "reach across", "D": "drink from a cup", "C": "comb hair"}
UE_LICENCE = "MIT (Copyright (c) 2021 MiaH-kin; notice in benchmarks/corpus/README.md)"


def git_head(repo: Path) -> str:
    return subprocess.run([GIT, "-C", str(repo), "rev-parse", "HEAD"], capture_output=True,
                          text=True, check=True).stdout.strip()


def git_text(repo: Path, path: str) -> str:
    """A file of the checkout: from its work tree if it has one, else from HEAD."""
    p = repo / path
    if p.exists():
        return p.read_text(encoding="utf-8-sig")
    out = subprocess.run([GIT, "-C", str(repo), "show", f"HEAD:{path}"], capture_output=True,
                         check=True).stdout
    return out.decode("utf-8-sig")


def git_list(repo: Path, under: str) -> list[str]:
    out = subprocess.run([GIT, "-C", str(repo), "ls-tree", "--name-only", "HEAD", under + "/"],
                         capture_output=True, text=True, check=True).stdout
    return sorted(out.split())


# -- UE-ADL -------------------------------------------------------------------------------
def read_vicon_csv(text: str) -> tuple[float, dict[str, np.ndarray]]:
    """(rate Hz, marker name -> (N, 3) mm, NaN where missing) of a Vicon Nexus CSV export."""
    lines = text.splitlines()
    rate = float(lines[1].split(",")[0])
    names = [n.split(":")[-1] for n in lines[2].split(",")[2::3] if n]
    rows = list(csv.reader(io.StringIO("\n".join(ln for ln in lines[5:] if ln.strip()))))
    width = 2 + 3 * len(names)
    a = np.full((len(rows), width), np.nan)
    for i, r in enumerate(rows):
        vals = [float(v) if v.strip() else np.nan for v in r[:width]]
        a[i, :len(vals)] = vals
    return rate, {n: a[:, 2 + 3 * k:5 + 3 * k] for k, n in enumerate(names)}


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising |R src + t - dst| (rows are points)."""
    cs, cd = src.mean(0), dst.mean(0)
    h = (src - cs).T @ (dst - cd)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cd - r @ cs


def carry(template: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame the rigid transform template -> frame (frames: (N, m, 3), NaN = missing):
    (R (N,3,3), t (N,3), ok (N,) at least 3 visible markers)."""
    n = frames.shape[0]
    rs, ts, ok = np.full((n, 3, 3), np.nan), np.full((n, 3), np.nan), np.zeros(n, bool)
    for i in range(n):
        vis = np.isfinite(frames[i]).all(axis=1)
        if vis.sum() >= 3:
            rs[i], ts[i] = kabsch(template[vis], frames[i][vis])
            ok[i] = True
    return rs, ts, ok


def frame_from(y: np.ndarray, z_approx: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation whose columns are x, y, z: y given, z as near z_approx, x = y x z."""
    y = y / np.linalg.norm(y, axis=-1, keepdims=True)
    x = np.cross(y, z_approx)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=-1)


def longest_run(ok: np.ndarray) -> slice:
    best, start = (0, 0), None
    for i, v in enumerate([*ok.tolist(), False]):
        if v and start is None:
            start = i
        elif not v and start is not None:
            if i - start > best[1] - best[0]:
                best = (start, i)
            start = None
    return slice(*best)


def _mirror(markers: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: v * np.array([-1.0, 1.0, 1.0]) for k, v in markers.items()}


class Subject:
    """One UE-ADL subject's static calibration, for one side."""

    #: technical cluster -> the anatomical landmarks it carries
    CLUSTERS: ClassVar[dict[str, tuple[str, ...]]] = {
        "UAR": ("GTH", "LEP", "MEP"), "LAR": ("SPR", "SPU"), "HAN": ()}

    def __init__(self, static: dict[str, np.ndarray], side: str):
        m = static if side == "R" else _mirror(static)
        s = side
        mean = {k: np.nanmean(v, axis=0) for k, v in m.items()}
        self.side = side
        self.templates = {c: np.array([mean[f"{s}{c}{i}"] for i in range(1, 5)]) for c in self.CLUSTERS}
        self.local = {}
        for c, marks in self.CLUSTERS.items():
            tpl = self.templates[c]
            ctr = tpl.mean(0)
            for mk in marks:
                self.local[mk] = (c, mean[f"{s}{mk}"] - ctr)
        # hand frame in the static trial, then in the hand cluster's (template) coordinates
        wrist = (mean[f"{s}SPR"] + mean[f"{s}SPU"]) / 2
        rh = frame_from(wrist - mean[f"{s}FB"], mean[f"{s}SPR"] - mean[f"{s}SPU"])
        self.hand_local = rh  # template frame = lab frame of the static trial
        for k in (f"{s}SPR", f"{s}SPU", f"{s}FB", f"{s}LEP", f"{s}MEP", f"{s}GTH"):
            if not np.isfinite(mean[k]).all():
                raise ValueError(f"static trial lacks {k}")

    def angles(self, trial: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, slice, int]:
        """(angles (N, 4) rad in our conventions, shoulder (N, 3) rad, usable run, frames)."""
        m = trial if self.side == "R" else _mirror(trial)
        s = self.side
        fits, oks = {}, []
        for c in self.CLUSTERS:
            frames = np.stack([m[f"{s}{c}{i}"] for i in range(1, 5)], axis=1)
            r, t, ok = carry(self.templates[c], frames)
            fits[c] = (r, t)
            oks.append(ok)
        other = "L" if s == "R" else "R"
        sho = np.nanmean(np.stack([m[f"{s}SHO{i}"] for i in range(1, 5)]), axis=0)
        sho_o = np.nanmean(np.stack([m[f"{other}SHO{i}"] for i in range(1, 5)]), axis=0)
        oks.append(np.isfinite(sho).all(1) & np.isfinite(sho_o).all(1))
        ok = np.logical_and.reduce(oks)
        run = longest_run(ok)

        def land(mk):
            c, loc = self.local[mk]
            r, t = fits[c]
            ctr = self.templates[c].mean(0)
            return np.einsum("nij,j->ni", r[run], ctr + loc) + t[run]

        gth, lep, mep, spr, spu = (land(k) for k in ("GTH", "LEP", "MEP", "SPR", "SPU"))
        emid = (lep + mep) / 2
        r_hum = frame_from(gth - emid, lep - mep)
        r_fa = frame_from(emid - spu, spr - spu)
        r_hand = fits["HAN"][0][run] @ self.hand_local
        up = np.broadcast_to([0.0, 0.0, 1.0], gth.shape)
        r_th = frame_from(up, sho[run] - sho_o[run])
        elbow = Rotation.from_matrix(np.swapaxes(r_hum, 1, 2) @ r_fa).as_euler("ZXY")
        wrist = Rotation.from_matrix(np.swapaxes(r_fa, 1, 2) @ r_hand).as_euler("ZXY")
        shoulder = Rotation.from_matrix(np.swapaxes(r_th, 1, 2) @ r_hum).as_euler("YXY")
        q = np.stack([elbow[:, 0], elbow[:, 2] - math.pi / 2, wrist[:, 0], wrist[:, 1]], axis=1)
        return np.unwrap(q, axis=0), np.unwrap(shoulder, axis=0), run, len(ok)


def derive_ue_adl(repo: Path, subjects: list[str], tasks: str, sides: str, reps: str) -> tuple[dict, list]:
    refused = [s for s in subjects if s in FORBIDDEN]
    if refused:
        raise SystemExit(f"{', '.join(refused)}: held out by the reviewer, never used")
    commit = git_head(repo)
    arrays, manifest = {}, []
    for subj in subjects:
        _, static = read_vicon_csv(git_text(repo, f"{subj}/{subj}_static.csv"))
        names = set(git_list(repo, subj))
        for side in sides:
            cal = Subject(static, side)
            for task in tasks:
                for rep in reps:
                    path = f"{subj}/{subj}{task}{side}{rep}.csv"
                    if path not in names:
                        continue
                    rate, mk = read_vicon_csv(git_text(repo, path))
                    q, sh, run, total = cal.angles(mk)
                    name = f"ue_adl_{subj}_{task}{side}{rep}"
                    n = q.shape[0]
                    if n < 2.5 * rate:
                        print(f"skip {name}: usable run {n} of {total} frames")
                        continue
                    arrays[f"{name}/q"] = q.astype(np.float64)
                    arrays[f"{name}/shoulder"] = sh.astype(np.float64)
                    raw = {j: rawness(q[:, k], rate) for k, j in enumerate(ANGLES)}
                    manifest.append({
                        "name": name, "source": "ue_adl", "subject": subj, "task": UE_TASKS[task],
                        "side": "right" if side == "R" else "left", "rep": int(rep), "rate_hz": rate,
                        "samples": n, "frames": [run.start, run.stop], "of_frames": total,
                        "file": path, "repository": "github.com/MiaH-kin/UE_ADLdatabase",
                        "commit": commit, "licence": UE_LICENCE, "joints": list(ANGLES),
                        "shoulder": list(SHOULDER), "rawness": raw,
                        "raw": all(r["raw"] for r in raw.values())})
                    print(f"{name}: {n} frames ({run.start}-{run.stop} of {total}), raw "
                          + " ".join(f"{j}={r['d3_ratio']:.1f}/{r['top_band_db']:.0f}dB"
                                     for j, r in raw.items()), flush=True)
    return arrays, manifest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ue-adl", type=Path, help="checkout (or bare mirror) of MiaH-kin/UE_ADLdatabase")
    ap.add_argument("--subjects", default="ADL002,ADL003,ADL004,ADL006,ADL007,ADL008,ADL009,ADL010,"
                                          "ADL011,ADL012,ADL013,ADL014,ADL015,ADL016")
    ap.add_argument("--tasks", default="FADC")
    ap.add_argument("--sides", default="RL")
    ap.add_argument("--reps", default="1")
    ap.add_argument("--out", type=Path, default=HERE)
    args = ap.parse_args(argv)
    man_path = args.out / "manifest.json"
    manifest = json.loads(man_path.read_text()) if man_path.exists() else {"recordings": []}
    done = []
    if args.ue_adl:
        arrays, recs = derive_ue_adl(args.ue_adl, args.subjects.split(","), args.tasks, args.sides,
                                     args.reps)
        np.savez_compressed(args.out / "ue_adl.npz", **arrays)
        done.append(("ue_adl", recs))
    for source, recs in done:
        manifest["recordings"] = [r for r in manifest["recordings"] if r["source"] != source] + recs
    manifest["recordings"].sort(key=lambda r: r["name"])
    man_path.write_text(json.dumps(manifest, indent=1) + "\n")
    n = len(manifest["recordings"])
    print(f"{n} recordings, {sum(r['raw'] for r in manifest['recordings'])} raw by the check")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
