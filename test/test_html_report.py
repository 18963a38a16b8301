"""check_bag --html opened in a real headless browser (Debian's chromium, installed by
`make setup`): the page loads with no console message, renders one plot per movement with
drawn lines, a non-blank screenshot, and needs no network (every host unresolvable)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from test_check_bag import Run, write_run

from forearm_dynamics.cli.check_bag import main as check_bag

pytestmark = pytest.mark.slow

MOVEMENTS = (1, 28, 40)
#: As the machine notes say works here as root: no sandbox, no GPU, no background traffic.
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--host-resolver-rules=MAP * ~NOTFOUND",  # offline: any network use fails to resolve
         "--enable-logging=stderr", "--v=0")


def _chromium() -> str:
    path = shutil.which("chromium")
    if path is None:
        pytest.fail("chromium is not installed: `make setup` installs it (apt-get install chromium)")
    return path


def _browse(tmp_path: Path, page: Path, *args: str) -> subprocess.CompletedProcess:
    """Run chromium on the page until its scripts are done (virtual time: no wall-clock
    deadline on a loaded machine); a fresh profile each time."""
    profile = tmp_path / f"profile{len(list(tmp_path.glob('profile*')))}"
    return subprocess.run([_chromium(), *FLAGS, f"--user-data-dir={profile}",
                           "--virtual-time-budget=30000", *args, page.as_uri()],
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, "HOME": str(tmp_path)}, check=False)


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("html")
    bag = d / "run.mcap"
    write_run(bag, Run(movements=MOVEMENTS))
    out = d / "report.html"
    assert check_bag([str(bag), "--html", str(out)]) == 0
    return out


def test_the_report_is_one_self_contained_file(report):
    text = report.read_text(encoding="utf-8")
    # the page outside its scripts (plotly's bundle holds URLs in strings it never fetches)
    markup = re.sub(r"<script[^>]*>.*?</script>", "", text, flags=re.DOTALL)
    assert "<script src" not in text and "<link" not in markup  # nothing to fetch
    assert not re.search(r"(src|href)=['\"]?https?:", markup)
    assert "PASS: the data are right" in text
    assert text.count('class="movement-plot"') == len(MOVEMENTS)


def test_chromium_renders_one_plot_per_movement_without_console_messages(report, tmp_path):
    run = _browse(tmp_path, report, "--dump-dom")
    assert run.returncode == 0, run.stderr[-2000:]
    console = [line for line in run.stderr.splitlines() if "CONSOLE" in line]
    assert not console, console
    dom = run.stdout
    plots = re.findall(r'<div class="movement-plot">(.*?)(?=<div class="movement-plot">|</body>)',
                       dom, flags=re.DOTALL)
    assert len(plots) == len(MOVEMENTS)
    for k, plot in enumerate(plots):
        assert f'id="movement-{k}"' in plot
        assert "main-svg" in plot  # plotly drew it: the SVG exists only after its JS ran
        lines = re.findall(r'class="js-line"[^>]*\sd="M([^"]+)"', plot)
        lines += re.findall(r'\sd="M([^"]+)"[^>]*class="js-line"', plot)
        lines = [d for d in lines if not re.fullmatch(r"[\d.]+,[\d.]+h[\d.]+", d)]  # legend keys
        # every recorded/truth/reference trace (20 DOFs x 3) is a drawn line (plotly merges
        # collinear points, so a constant torque is one segment)
        assert len(lines) >= 3 * 20, (k, len(lines))
        assert all("L" in d for d in lines)
        assert max(d.count(",") for d in lines) > 30  # and a moving one has many points
    for hist in ("latency-histogram", "delivery-histogram"):
        assert re.search(rf'id="{hist}"[^>]*class="[^"]*js-plotly-plot', dom) or \
            re.search(rf'class="[^"]*js-plotly-plot[^"]*"[^>]*id="{hist}"', dom), hist


def test_the_screenshot_is_not_blank(report, tmp_path):
    shot = tmp_path / "report.png"
    run = _browse(tmp_path, report, "--window-size=1400,2600", f"--screenshot={shot}")
    assert run.returncode == 0 and shot.is_file(), run.stderr[-2000:]
    img = np.asarray(Image.open(shot).convert("RGB"), dtype=np.int16)
    assert img.shape[:2] == (2600, 1400)
    # not one colour: text, table lines and the drawn torque curves in many colours
    colours = np.unique(img.reshape(-1, 3), axis=0)
    assert len(colours) > 200, len(colours)
    # the lower half (the first movement's plot) has ink, not only page background
    lower = img[1400:]
    assert (np.abs(lower - lower[0, 0]).sum(axis=2) > 60).mean() > 0.02


def test_a_failed_run_says_fail_in_the_report(tmp_path):
    bag = tmp_path / "bad.mcap"
    write_run(bag, Run(movements=(28,), offset={2: 0.05}))  # wrist_flexion off by 5 % of ptp
    out = tmp_path / "bad.html"
    assert check_bag([str(bag), "--html", str(out)]) == 1
    text = out.read_text(encoding="utf-8")
    assert 'class="verdict fail"' in text and "wrist_flexion" in text


def test_a_recording_without_markers_gets_one_segment_plot(tmp_path, capsys):
    bag = tmp_path / "session.mcap"
    write_run(bag, Run(movements=(28,), markers=False))
    out = tmp_path / "session.html"
    assert check_bag([str(bag), "--html", str(out)]) == 0
    text = out.read_text(encoding="utf-8")
    assert text.count('class="movement-plot"') == 1 and 'id="segment-0"' in text
    assert "scored as one segment" in text and "PASS" in text


def test_html_with_baseline_is_refused_in_one_line(tmp_path, capsys):
    bag = tmp_path / "a.mcap"
    write_run(bag, Run(movements=(28,)))
    code = check_bag([str(bag), "--baseline", str(bag), "--html", str(tmp_path / "x.html")])
    err = capsys.readouterr().err
    assert code == 2 and "--html" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.html").exists()
