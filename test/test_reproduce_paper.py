"""reproduce_paper as a user runs it: a process of its own, into a new folder."""

import json
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.cli, pytest.mark.slow]


def test_reproduce_paper_reuses_its_cache_and_reproduces_the_committed_numbers(tmp_path, paper_results):
    """A user's run into a new folder: no terminal (no progress bar), the committed cache
    (seeded from the checkout), the same numbers."""
    pytest.importorskip("matplotlib")
    r = subprocess.run([sys.executable, "-m", "forearm_dynamics.cli.reproduce_paper", "--out",
                        str(tmp_path)], capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stderr == ""  # no progress bar in a redirected log
    new = json.loads((tmp_path / "results.json").read_text(encoding="utf-8"))
    assert new["cache"]["misses"] == 0 and new["cache"]["hits"] > 10
    for name in paper_results["models"]:
        for size, m in paper_results["models"][name].items():
            for group, metrics in m["summary"].items():
                for metric, s in metrics.items():
                    got = new["models"][name][size]["summary"][group][metric]
                    for k, v in s.items():  # None where a summary is empty (JSON has no NaN)
                        assert got[k] == (v if v is None else pytest.approx(v, rel=1e-9)), (
                            name, size, group, metric, k)
    for name in ("fig3.png", "fig4.png", "fig5.png", "fig6.png", "fig7.png"):
        assert (tmp_path / name).stat().st_size > 10_000
    assert (tmp_path / "cache.json").stat().st_size > 1000  # the run's own copy
