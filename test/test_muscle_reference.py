"""The muscle layer against OpenSim and the source geometry, and bag_muscles through real files.

- cached reference (forearm_dynamics/data/muscle_so_reference.npz, `make muscle-reference`):
  made from the shipped muscle model (its SHA-256), OpenSim 4.6's StaticOptimization of 13
  library movements; our per-sample QP (as the node) on the same frames meets issue 31's
  targets: per-muscle RMS(Δactivation) <= 0.01, force RMS <= 2 % of F0, correlation >= 0.95
  where the peak activation >= 0.05; frames rejected (reserve use, torque mismatch) stay few;
- the exact-geometry solve (MuJoCo tendon Jacobians + scipy BVLS, cached beside it): the
  same bound as against OpenSim, RMS(Δa) <= 0.01 per muscle (what differs is the surrogate's
  geometry error alone; known to fail for BRA, 0.017: at full elbow extension its surrogate
  moment arm is -0.51 mm where MyoArm's is +0.68 mm, so the QP cannot use it as a flexor);
- OpenSim live on a few frames (slow): the model is built here and SO run now, so the cached
  file is not the only evidence;
- bag_muscles: a bag of joint_torques in, muscle_forces and muscle_reserves out, read back by
  an independent reader (rosbags), same headers, the numbers of offline/muscles.compute.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from rosproc import ros_env
from support.jointstate import joint_state_bytes

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.bag import BagWriter, TopicQos
from forearm_dynamics.movements import get_movement
from forearm_dynamics.muscle_validation.opensim_so import model_digest, our_movement
from forearm_dynamics.muscle_validation.reference import (
    REFERENCE_FILE,
    TARGET_CORR,
    TARGET_FORCE_PCT,
    TARGET_RMS_DA,
    accepted_frames,
    figures,
    load_reference,
)
from forearm_dynamics.muscles import load_muscle_model

pytestmark = pytest.mark.slow  # every test here takes seconds (OpenSim, subprocesses, solves)

EXACT_BOUND = TARGET_RMS_DA  # 0.01, the target against OpenSim


@pytest.fixture(scope="module")
def compared():
    ref = load_reference()
    mm = load_muscle_model()
    arm = build_model("segmented", 50)
    A, F, Q, T = [], [], [], []
    for i, mid in enumerate(ref.movement_ids):
        sl = ref.frames(i)
        mv = get_movement(int(mid))
        ser, tau = our_movement(arm, mm, mv, ref.times[sl])
        A.append(ser.activations)
        F.append(ser.forces)
        Q.append(mv.evaluate(ref.times[sl])[0])
        T.append(tau)
    return ref, mm, *map(np.vstack, (A, F, Q, T))


@pytest.mark.slow
def test_reference_is_of_the_shipped_model(compared):
    ref, mm = compared[:2]
    assert ref.meta["muscle_model_sha256"] == model_digest(mm), \
        f"{REFERENCE_FILE.name} was made from another muscle model: run make muscle-reference"
    assert ref.names == mm.names
    assert len(ref.movement_ids) >= 10


@pytest.mark.slow
def test_our_static_optimisation_matches_opensim(compared):
    ref, mm, A, F, Q, T = compared
    keep, rejected = accepted_frames(mm, Q, T, ref.forces, ref.reserves)
    assert keep.mean() >= 0.9, rejected
    f = figures(mm, A, ref.activations, keep, rejected, F, ref.forces)
    bad = [f.row(i) for i in range(mm.n) if f.rms_da[i] > TARGET_RMS_DA
           or f.force_rms_pct[i] > TARGET_FORCE_PCT
           or (f.peak[i] >= 0.05 and not f.corr[i] >= TARGET_CORR)]
    assert not bad, bad
    assert f.passes()


# Issue 31's target, not met: BRA's surrogate moment arm at full elbow extension is -0.51 mm
# where MyoArm's is +0.68 mm (activation RMS 0.017 > 0.01). strict: it fails the day the fit
# keeps the sign (the refit with sign checks is drafted in the muscle-fix branch history).
@pytest.mark.xfail(strict=True, reason="issue 31 open: BRA surrogate sign at full elbow extension "
                   "(activation RMS 0.017 vs the exact geometry, bound 0.01)")
@pytest.mark.slow
def test_surrogate_geometry_against_the_exact_geometry_solve(compared):
    ref, mm, A = compared[:3]
    assert ref.exact_activations is not None, "reference made with --no-exact"
    g = figures(mm, A, ref.exact_activations, np.ones(len(A), bool), {})
    bad = [g.row(i) for i in range(mm.n) if g.rms_da[i] > EXACT_BOUND]
    assert not bad, bad


@pytest.mark.slow
def test_opensim_live_on_a_few_frames():
    osim = pytest.importorskip("opensim")  # the optional [reference] extra; only a guard
    assert osim.__version__.startswith("4.")
    from forearm_dynamics.muscle_validation.opensim_so import (
        build_so_model,
        opensim_geometry,
        run_static_optimization,
    )

    mm = load_muscle_model()
    arm = build_model("segmented", 50)
    model = build_so_model(arm.tree, mm)
    mv = get_movement(36)  # open hand while pronating: forearm, wrist and finger muscles
    q, qd, _ = mv.evaluate(np.array([0.7]))
    R, L, V = opensim_geometry(model, mm, q[0], qd[0])
    R2, L2, V2 = mm.geometry(q[0], qd[0])
    np.testing.assert_allclose(R, R2, rtol=0, atol=1e-12)  # OpenSim sees the node's geometry
    np.testing.assert_allclose(L, L2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(V, V2, rtol=0, atol=1e-12)
    t = mv.sample_times(1000.0)
    res = run_static_optimization(model, mm, t, mv.evaluate(t)[0], np.array([0.5, 0.6, 0.7, 0.8]))
    ser, tau = our_movement(arm, mm, mv, res.times)
    keep, rejected = accepted_frames(mm, mv.evaluate(res.times)[0], tau, res.forces, res.reserves)
    assert keep.all(), rejected
    np.testing.assert_allclose(ser.activations, res.activations, rtol=0, atol=1e-3)


@pytest.mark.cli
def test_bag_muscles_through_real_files(tmp_path):
    from rosbags.highlevel import AnyReader

    from forearm_dynamics.codec.jointstate import JointSeries
    from forearm_dynamics.offline.muscles import compute

    mv = get_movement(46)
    t = mv.sample_times(200.0)
    q, qd, qdd = mv.evaluate(t)
    tau = build_model("segmented", 50).inverse_dynamics_batch(q, qd, qdd)
    stamps = 1_700_000_000 * 10**9 + (t * 1e9).astype(np.int64) + 1
    src, dst = tmp_path / "torques.mcap", tmp_path / "muscles.mcap"
    w = BagWriter(src)
    ch = w.add_topic("/joint_torques", "sensor_msgs/msg/JointState", TopicQos(depth=1000))
    for k in range(len(t)):
        w.write(ch, joint_state_bytes(int(stamps[k]), q[k], qd[k], tau[k]), int(stamps[k]))
    w.close()
    r = subprocess.run([sys.executable, "-m", "forearm_dynamics.cli.bag_muscles", str(src),
                        str(dst), "--decimation", "2"], capture_output=True, text=True, timeout=300,
                       env=ros_env(), check=False)
    assert r.returncode == 0, r.stderr
    mm = load_muscle_model()
    got: dict[str, list] = {"/muscle_forces": [], "/muscle_reserves": []}
    with AnyReader([dst]) as reader:
        conns = [c for c in reader.connections if c.topic in got]
        for conn, _ts, raw in reader.messages(connections=conns):
            got[conn.topic].append(reader.deserialize(raw, conn.msgtype))
    want = stamps[::2]
    for topic, msgs in got.items():
        assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs] == want.tolist(), topic
    assert all(tuple(m.name) == mm.names for m in got["/muscle_forces"])
    assert all(tuple(m.name) == JOINT_NAMES for m in got["/muscle_reserves"])
    off = compute(JointSeries("joint_torques", JOINT_NAMES, stamps, stamps, [""] * len(t), q, qd, tau),
                  mm, decimation=2)
    np.testing.assert_array_equal(np.array([m.position for m in got["/muscle_forces"]]), off.activations)
    np.testing.assert_array_equal(np.array([m.effort for m in got["/muscle_forces"]]), off.forces)
    np.testing.assert_array_equal(np.array([m.effort for m in got["/muscle_reserves"]]), off.reserves)
    # a second run on its own output is refused by name, exit 2 (no traceback)
    r2 = subprocess.run([sys.executable, "-m", "forearm_dynamics.cli.bag_muscles", str(dst),
                         str(tmp_path / "again.mcap")], capture_output=True, text=True, timeout=300,
                        env=ros_env(), check=False)
    assert r2.returncode == 2 and "muscle_forces" in r2.stderr and "Traceback" not in r2.stderr
    # bag_export --muscles: the same numbers as columns (CSV read back by numpy)
    csv = tmp_path / "muscles.csv"
    r3 = subprocess.run([sys.executable, "-m", "forearm_dynamics.cli.bag_export", str(dst),
                         "--format", "csv", "--muscles", "--out", str(csv)],
                        capture_output=True, text=True, timeout=300, env=ros_env(), check=False)
    assert r3.returncode == 0, r3.stderr
    header = csv.read_text().splitlines()[0].split(",")
    table = np.loadtxt(csv, delimiter=",", skiprows=1)
    assert header[:2] == ["time", "stamp_ns"] and len(table) == len(want)
    for i, name in enumerate(mm.names[:5]):
        np.testing.assert_array_equal(table[:, header.index(f"{name}_activation")], off.activations[:, i])
        np.testing.assert_array_equal(table[:, header.index(f"{name}_force")], off.forces[:, i])
    np.testing.assert_array_equal(table[:, header.index("elbow_flexion_reserve")], off.reserves[:, 0])


@pytest.mark.cli
def test_check_bag_html_shows_the_activations(tmp_path):
    from test_check_bag import Run, write_run

    from forearm_dynamics.cli.check_bag import main as check_bag
    from forearm_dynamics.offline.muscles import bag_muscles

    run, muscles = tmp_path / "run.mcap", tmp_path / "muscles.mcap"
    write_run(run, Run(movements=(40,)))
    res, _counts, _cfg = bag_muscles(run, muscles)
    out, plain = tmp_path / "report.html", tmp_path / "plain.html"
    assert check_bag([str(muscles), "--html", str(out)]) == 0
    assert check_bag([str(run), "--html", str(plain)]) == 0
    text = out.read_text(encoding="utf-8")
    assert "<h2>Muscles</h2>" in text and 'id="muscles"' in text
    peak = res.activations.max(axis=0)
    top = load_muscle_model().names[int(peak.argmax())]
    assert f"<td>{top}</td><td class=\"num\">{peak.max():.3f}</td>" in text.replace("'", '"')
    assert "<h2>Muscles</h2>" not in plain.read_text(encoding="utf-8")  # no muscles, no section
