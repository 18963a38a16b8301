"""ANSUR II statistics for the subject-parameter part of the σ: how far a person's forearm and
hand differ from what their stature and body mass predict.

Source: ANSUR II, the 2012 anthropometric survey of U.S. Army personnel (Gordon CC et al.
2014, "2012 Anthropometric Survey of U.S. Army Personnel: Methods and Summary Statistics",
NATICK/TR-15/007), public data files ANSUR_II_MALE_Public.csv (4082 men) and
ANSUR_II_FEMALE_Public.csv (1986 women); a work of the U.S. Government, public domain.
The columns used here (lengths mm, weightkg in 0.1 kg) are copied unchanged, one row per
subject, to benchmarks/data/ansur2_arm.csv (`--from-ansur DIR` re-extracts and checks the
full files' SHA-256); the 300 kB subset, not the 3 MB survey, is what the repository keeps.

What is derived (per sex, and both sexes pooled for a body size of unknown sex): the
residuals of five log dimensions after a least-squares regression on (1, ln stature,
ln body mass), and their covariance. The dimensions are the model's own size factors
(anthropometry.BodySize) and the two segment masses the model scales with body mass:
    forearm_length  radialestylionlength (what body_sizes.yaml calls forearm length)
    hand_length     handlength
    hand_breadth    handbreadth
    forearm_mass    a frustum's volume: radiale-stylion x (C1² + C1 C2 + C2²) / 12π,
                    C1 forearmcircumferenceflexed, C2 wristcircumference
    hand_mass       a cylinder's volume: handlength x handcircumference² / 4π
Segment masses are not measured in ANSUR; segment mass ∝ volume at a constant density
(the premise of the cadaver and geometric segment models, e.g. Zatsiorsky's and
Hanavan's) gives their relative spread from lengths and girths that are. In log space only
relative spread matters, so the constants (π, density) drop out; what the proxy leaves out
(density and shape variation between people) makes the mass spread a lower bound.

    python -m forearm_dynamics.uncertainty.subject_stats          # subset -> data JSON
    python -m forearm_dynamics.uncertainty.subject_stats --from-ansur DIR   # full CSVs first

test_uncertainty_subject.py checks that the data JSON is what the subset gives.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import sys
from importlib import resources
from pathlib import Path

import numpy as np

TABLE = "subject_ansur.json"
SUBSET = Path(__file__).resolve().parents[2] / "benchmarks" / "data" / "ansur2_arm.csv"
#: the full public files this was made from (the copy in github.com/KhadijehValipour/ANSUR,
#: commit d20788f, whose percentiles are those of config/body_sizes.yaml)
FULL = {"male": ("ANSUR_II_MALE_Public.csv",
                 "177a9ee248a4d938190c83e18cbf04937de9f864d8ac4be07e757d3f018a35ab"),
        "female": ("ANSUR_II_FEMALE_Public.csv",
                   "4854f4888146c81690b374d07d044008798ae4a21552afb90823ebd64e04b99f")}
COLUMNS = ("SubjectId", "Gender", "stature", "weightkg", "radialestylionlength", "handlength",
           "handbreadth", "handcircumference", "forearmcircumferenceflexed", "wristcircumference")
DIMS = ("forearm_length", "hand_length", "hand_breadth", "forearm_mass", "hand_mass")
GROUPS = ("male", "female", "all")
SOURCE = ("ANSUR II 2012 (Gordon CC et al. 2014, NATICK/TR-15/007), public data files "
          "ANSUR_II_MALE_Public.csv (n = 4082) and ANSUR_II_FEMALE_Public.csv (n = 1986)")
LICENCE = "public domain (a work of the U.S. Government, 17 U.S.C. 105)"


def extract_subset(ansur_dir: Path, out: Path = SUBSET) -> Path:
    """Copy COLUMNS of both full survey files (checked by SHA-256) into one small CSV."""
    rows = []
    for sex, (name, sha) in FULL.items():
        raw = (ansur_dir / name).read_bytes()
        got = hashlib.sha256(raw).hexdigest()
        if got != sha:
            raise ValueError(f"{name}: SHA-256 {got} is not the {sex} file this was made from ({sha})")
        reader = csv.DictReader(raw.decode("latin-1").splitlines())
        rows += [[r[c] for c in COLUMNS] for r in reader]
    with open(out, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(COLUMNS)
        w.writerows(rows)
    return out


def read_subset(path: Path = SUBSET) -> dict[str, np.ndarray]:
    """Columns of the subset in SI units (m, kg); "sex" as "male"/"female"."""
    with open(path, encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    out: dict[str, np.ndarray] = {"sex": np.array([r["Gender"].strip().lower() for r in rows])}
    for c in COLUMNS[2:]:
        v = np.array([float(r[c]) for r in rows])
        out[c] = v / 10.0 if c == "weightkg" else v / 1000.0
    return out


def log_dimensions(cols: dict[str, np.ndarray]) -> np.ndarray:
    """(N, 5) ln of DIMS (volume proxies for the masses, see the module docstring)."""
    length = cols["radialestylionlength"]
    c1, c2 = cols["forearmcircumferenceflexed"], cols["wristcircumference"]
    forearm_volume = length * (c1 * c1 + c1 * c2 + c2 * c2) / (12.0 * np.pi)
    hand_volume = cols["handlength"] * cols["handcircumference"] ** 2 / (4.0 * np.pi)
    return np.log(np.stack([length, cols["handlength"], cols["handbreadth"], forearm_volume,
                            hand_volume], axis=1))


def regressors(cols: dict[str, np.ndarray]) -> np.ndarray:
    return np.stack([np.ones(len(cols["stature"])), np.log(cols["stature"]), np.log(cols["weightkg"])], 1)


def group_stats(x: np.ndarray, y: np.ndarray) -> dict:
    """Least squares of y (N, 5) on x (N, 3); residual covariance with N - 3 degrees of freedom."""
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    r = y - x @ coef
    n = len(y)
    cov = r.T @ r / (n - x.shape[1])
    return {"n": int(n), "coef": coef.tolist(), "residual_cov": cov.tolist(),
            "residual_sd": np.sqrt(np.diag(cov)).tolist(), "raw_sd": y.std(axis=0, ddof=1).tolist(),
            "residuals": r}


def derive(path: Path = SUBSET) -> tuple[dict, dict[str, np.ndarray]]:
    """(the data JSON's document, the residuals (N, 5) per group) from the subset CSV."""
    cols = read_subset(path)
    x, y = regressors(cols), log_dimensions(cols)
    groups, residuals = {}, {}
    for g in GROUPS:
        m = np.ones(len(y), bool) if g == "all" else cols["sex"] == g
        st = group_stats(x[m], y[m])
        residuals[g] = st.pop("residuals")
        groups[g] = st
    doc = {
        "source": SOURCE, "licence": LICENCE,
        "subset": "benchmarks/data/ansur2_arm.csv",
        "subset_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "full_sha256": {FULL[s][0]: FULL[s][1] for s in FULL},
        "command": "python -m forearm_dynamics.uncertainty.subject_stats",
        "dims": list(DIMS),
        "regressors": ["1", "ln stature (m)", "ln body mass (kg)"],
        "proxies": {"forearm_mass": "radialestylionlength x (C1^2 + C1 C2 + C2^2) / 12 pi, C1 "
                                    "forearmcircumferenceflexed, C2 wristcircumference (frustum volume)",
                    "hand_mass": "handlength x handcircumference^2 / 4 pi (cylinder volume)"},
        "groups": groups,
    }
    return doc, residuals


def load_stats() -> dict:
    return json.loads(resources.files("forearm_dynamics").joinpath("data", TABLE).read_text())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--from-ansur", type=Path, metavar="DIR",
                   help="first re-extract the subset from the full survey CSVs in DIR")
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if args.from_ansur is not None:
            print(f"wrote {extract_subset(args.from_ansur)}")
        doc, _ = derive()
    except (OSError, ValueError) as exc:  # a missing file (an installed package has no subset)
        print(f"subject_stats: error: {exc} (run it in a source checkout)", file=sys.stderr)
        return 2
    out = Path(__file__).resolve().parents[1] / "data" / TABLE
    out.write_text(json.dumps(doc, indent=1) + "\n")
    for g in GROUPS:
        sds = doc["groups"][g]["residual_sd"]
        sd = ", ".join(f"{d} {100 * s:.1f} %" for d, s in zip(DIMS, sds, strict=True))
        print(f"{g} (n = {doc['groups'][g]['n']}): residual SD {sd}")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
