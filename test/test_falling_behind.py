"""A torque_node more than half a queue behind its live input says so (a real process).

Past its queue (qos_depth) DDS drops the oldest input samples and no event tells the node, so
the node watches how far behind the stamps it runs (callback entry minus the sample's stamp)
and warns, naming the queue and the fix. Falling behind is made deterministic here: the
feeder stamps its samples 1 ms apart but sends them 2 ms apart, so each arrives 1 ms more
behind its stamp than the one before, however fast the machine is. The same node, fed
samples stamped as they are sent, stays quiet (its threshold is then 0.4 s of real lag).
"""

from __future__ import annotations

import signal

import pytest
from faultkit import TorqueHarness, start_feeder

pytestmark = [pytest.mark.faults, pytest.mark.ros]

WARNING = "s behind the input's stamps, past half of what the input queue holds"


def _feed(h: TorqueHarness, procs, tmp_path, name: str, step_ns: int) -> None:
    seen = h.diag.count
    feeder, _stamps, log = start_feeder(procs, tmp_path, h.domain, count=1500, rate_hz=500.0,
                                        step_ns=step_ns, name=name)
    h.peer.spin_until(lambda: feeder.poll() is not None, 120)  # a hang guard
    assert feeder.returncode == 0, log.read_text()
    # the node warns at its /diagnostics period: wait for two after the feed
    h.peer.spin_until(lambda: h.diag.count >= seen + 2, 30)
    h.diag.fresh()


def test_a_node_behind_its_input_says_so(procs, tmp_path) -> None:
    h = TorqueHarness(procs, "-p", "qos_depth:=400")
    try:
        _feed(h, procs, tmp_path, "live", step_ns=0)  # stamped as sent: 2 ms apart, live
        assert WARNING not in h.proc.output(), h.proc.output()[-2000:]
        _feed(h, procs, tmp_path, "lagging", step_ns=1_000_000)  # 1.5 s behind at the end
        out = h.proc.output()
        line = next((x for x in out.splitlines() if WARNING in x), None)
        assert line is not None, out[-3000:]
        # the queue in seconds at the stamps' own rate (1 kHz), and the fix
        assert "(400 samples = 0.40 s at 1000 Hz)" in line, line
        assert "raise qos_depth" in line and "Traceback" not in out
    finally:
        h.close()
        assert h.proc.stop(signal.SIGINT) == 0
