"""The real corpus and its scoring (issue 29): the rawness check, NRMSE with a settling time
and the first second apart, the ratio to the Butterworth, σ coverage, on synthetic data
with known answers; the split (by subject or source, the reviewer's subjects absent); and
the docs tables, which must be what benchmarks/real_corpus.py generates from the committed
benchmarks/real_corpus.json."""

from __future__ import annotations

import copy
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import butter, sosfiltfilt

from forearm_dynamics.offline import realscore

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "benchmarks"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))


# -- rawness -------------------------------------------------------------------------------
def _movement(fs: float, seconds: float = 8.0) -> np.ndarray:
    t = np.arange(0, seconds, 1 / fs)
    return 0.6 * np.sin(2 * np.pi * 0.4 * t) + 0.2 * np.sin(2 * np.pi * 1.3 * t + 1.0)


def test_rawness_tells_a_raw_recording_from_a_filtered_one() -> None:
    fs = 100.0
    rng = np.random.default_rng(3)
    raw = _movement(fs) + rng.normal(0, np.radians(0.1), int(8 * fs))
    verdict = realscore.rawness(raw, fs)
    assert verdict["raw"] and verdict["d3_ratio"] > 5 and verdict["top_band_db"] > -6, verdict
    # the same recording as its authors might publish it: 4th-order Butterworth at 10 Hz
    filtered = sosfiltfilt(butter(4, 10.0, fs=fs, output="sos"), raw)
    verdict = realscore.rawness(filtered, fs)
    assert not verdict["raw"] and verdict["d3_ratio"] < 2 and verdict["top_band_db"] < -25, verdict
    # coloured measurement noise (an IK artefact, 30 ms correlation) is still raw
    a = math.exp(-1 / (0.03 * fs))
    w = rng.normal(0, np.radians(0.3), int(8 * fs))
    col = np.zeros_like(w)
    for k in range(1, len(w)):
        col[k] = a * col[k - 1] + math.sqrt(1 - a * a) * w[k]
    assert realscore.rawness(_movement(fs) + col, fs)["raw"]


# -- scoring ---------------------------------------------------------------------------------
def _stamps(n: int, fs: float) -> np.ndarray:
    return 1_000_000_000 + np.round(np.arange(n) / fs * 1e9).astype(np.int64)


def test_nrmse_after_settling_and_the_first_second_apart() -> None:
    fs, n = 100.0, 500  # 5 s
    stamps = _stamps(n, fs)
    t = np.arange(n) / fs
    ref = np.stack([np.sin(2 * np.pi * 0.5 * t), 3 * np.cos(2 * np.pi * 0.2 * t)], axis=1)
    ptp = np.ptp(ref, axis=0)
    est = ref.copy()
    est[t < 1.0] += [0.5, -2.0]  # the start: large errors
    est[t >= 1.0] += [0.02, 0.3]  # settled: small constant errors
    sc = realscore.score(stamps, est, stamps, ref)
    np.testing.assert_allclose(sc.settled, [0.02 / ptp[0], 0.3 / ptp[1]], rtol=1e-12)
    np.testing.assert_allclose(sc.first, [0.5 / ptp[0], 2.0 / ptp[1]], rtol=1e-12)
    assert (sc.settled_samples, sc.first_samples) == (400, 100)
    # a delayed estimator outputs a subset of the stamps: only those are scored
    sub = slice(0, n - 20)
    sc2 = realscore.score(stamps[sub], est[sub], stamps, ref)
    np.testing.assert_allclose(sc2.settled, sc.settled, rtol=1e-12)
    assert sc2.settled_samples == 380
    with pytest.raises(ValueError, match="stamps of the reference"):
        realscore.score(stamps[:5] + 1, est[:5], stamps, ref)


def test_node_outputs_stamp_a_delayed_estimate_with_the_sample_it_estimates() -> None:
    fs, n = 100.0, 300
    stamps = _stamps(n, fs)
    q = np.zeros((n, 20))
    q[:, 0] = _movement(fs, n / fs)
    causal = realscore.node_outputs(stamps, q, "butterworth", {"butterworth_cutoff_hz": 6.0})
    assert causal.stamps_ns[-1] == stamps[-1]
    delayed = realscore.node_outputs(stamps, q, "kalman", {"delay_s": 0.1})
    assert delayed.stamps_ns[-1] == stamps[-1 - 10]  # 0.1 s = 10 samples back, never drained
    assert np.isin(delayed.stamps_ns, stamps).all() and (np.diff(delayed.stamps_ns) > 0).all()


def test_ratio_and_summary_medians_and_worst_per_half() -> None:
    import real_corpus

    def rec(name, half, ratios):
        ests = {}
        for label in real_corpus.ESTIMATORS:
            r = {j: x for j, x in ratios.items()} if label == "kalman" else {j: 1.0 for j in ratios}
            ests[label] = {"settled": dict(r), "first_second": dict(r), "ratio_settled": dict(r),
                           "ratio_first_second": dict(r), "bag_torques_max_dev_nm": 0.0}
        return {"name": name, "half": half, "source": "s", "subject": name, "joints": list(ratios),
                "raw": True, "estimators": ests,
                "sigma": {"inside": [95] * len(ratios), "n": 100, "sum_std2": [4.0] * len(ratios),
                          "sum_err2": [1.0] * len(ratios)}}
    recs = [rec("a", "held_out", {"elbow_flexion": 0.5, "pro_sup": 1.5}),
            rec("b", "held_out", {"elbow_flexion": 0.8, "pro_sup": 0.9}),
            rec("c", "tuning", {"elbow_flexion": 3.0})]
    s = real_corpus.summary(recs)
    k = s["held_out"]["estimators"]["kalman"]["settled"]
    assert k["ratio"] == {"median": pytest.approx(0.85), "worst": 1.5, "n": 4}
    assert k["worse_than_baseline"] == 1 and k["worst_series"] == "a:pro_sup"
    assert s["tuning"]["estimators"]["kalman"]["settled"]["ratio"]["worst"] == 3.0
    cov = s["held_out"]["sigma_coverage"]["elbow_flexion"]
    assert cov["inside_1p96"] == pytest.approx(0.95) and cov["rms_std_over_rmse"] == pytest.approx(2.0)


def test_coverage_counts_errors_inside_1p96_sigma() -> None:
    err = np.array([[0.0, 1.0], [1.0, 3.0], [2.5, -1.0], [0.1, 0.1]])
    std = np.array([[1.0, 1.0], [1.0, 1.0], [1.0, 1.0], [np.inf, 1.0]])
    c = realscore.coverage(err, std)
    np.testing.assert_allclose(c["inside_1p96"], [2 / 3, 2 / 3])
    assert c["samples"] == 3


# -- the corpus and its split ----------------------------------------------------------------
def test_corpus_split_by_subject_or_source_and_raw() -> None:
    from benchmarks.corpus import load, split

    sp = split()
    assert not set(sp["tuning"]["ue_adl"]) & set(sp["held_out"]["ue_adl"])
    assert not set(sp["tuning"]["sources"]) & set(sp["held_out"]["sources"])
    halves = {h: load(h) for h in ("tuning", "held_out")}
    assert len(halves["tuning"]) + len(halves["held_out"]) >= 10
    subjects = {h: {r.subject for r in rs} for h, rs in halves.items()}
    assert not subjects["tuning"] & subjects["held_out"]
    for rs in halves.values():
        for r in rs:
            assert r.subject not in ("ADL001", "ADL005")
            assert r.meta["raw"], r.name
            assert (np.diff(r.stamps_ns) > 0).all() and np.isfinite(r.q).all()
    manifest = json.loads((ROOT / "benchmarks" / "corpus" / "manifest.json").read_text(encoding="utf-8"))
    assert not any(("ADL001" in r["name"]) or ("ADL005" in r["name"]) for r in manifest["recordings"])


# -- docs generated from the committed benchmark output -------------------------------------
def _results() -> dict:
    return json.loads((ROOT / "benchmarks" / "real_corpus.json").read_text(encoding="utf-8"))


def test_docs_tables_are_the_committed_benchmark_output() -> None:
    import real_corpus

    for path, text in real_corpus.docs_parts(_results()):
        doc = (ROOT / path).read_text(encoding="utf-8")
        assert text in doc, f"{path}: the real-corpus table differs from benchmarks/real_corpus.json; " \
                            "run python benchmarks/real_corpus.py --docs"


def test_docs_check_fails_when_a_number_differs() -> None:
    import real_corpus

    res = _results()
    changed = copy.deepcopy(res)
    s = changed["summary"]["held_out"]["estimators"]["kalman"]["settled"]["ratio"]
    s["median"] += 0.01
    old, new = real_corpus.docs_parts(res), real_corpus.docs_parts(changed)
    assert all(a != b for (_, a), (_, b) in zip(old, new, strict=True))
