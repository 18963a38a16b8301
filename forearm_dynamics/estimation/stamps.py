"""When a stream's next sample continues the estimator's history, and the rates it supports.

One rule for every path that feeds an estimator sample by sample (torque_node and
null_echo_node through nodes/stream_node.py, bag_torques through offline/torques.py, the
Python API uncertainty.inverse_dynamics_with_std), so that the same stream restarts the
estimator at the same samples everywhere (node and bag_torques agree to 1e-9 N·m).

The jump rule (max_stamp_gap 0, the default: adaptive). A stamp step d after the previous
sample is judged against G:
- the stream's own interval known (the step before this one, any length): G = max(0.1 s,
  5 x that step). A 1 kHz stream that pauses 0.1 s is a gap; a steady 10 Hz (or 5 Hz, or
  1 Hz) stream is not, at any sample. A step that was a gap becomes the stream's interval
  in its turn, so a stream that changes rate (1 kHz -> 10 Hz) restarts once, not at every
  sample;
- the first step of a stream (nothing before it): G = FIRST_STEP_MAX_S (0.5 s): any stream
  of 2 Hz or more keeps its history from its second sample on.
  The first version judged every step after a restart against 0.1 s alone: a steady 10 Hz
  stream (steps of 100.5 ms) restarted the estimator at every sample (79 resets in 80
  samples: static torques only, issue 30).
- d > G: a gap (reset); d < -G: a jump back (the source restarted; reset); -G <= d <= 0:
  not increasing (the sample is refused); else the sample continues the history.
With max_stamp_gap > 0 the rule is that fixed G, whatever the stream.

Supported rates: the estimators are measured from 30 Hz to 1 kHz (benchmarks/estimation.py,
docs/estimation.md). Below MIN_SUPPORTED_RATE_HZ, torque_node says so at the first step of
its input (one line, and in /diagnostics) and estimates all the same.
"""

from __future__ import annotations

from dataclasses import dataclass

#: The adaptive rule's floor (s): shorter steps never restart the estimator.
MIN_ADAPTIVE_GAP_S = 0.1
#: The adaptive rule: a step longer than GAP_PERIODS x the step before it (and the floor).
GAP_PERIODS = 5
#: The first step of a stream, with no interval before it to compare with (2 Hz).
FIRST_STEP_MAX_S = 0.5
#: The lowest rate the estimators are measured at (benchmarks/estimation.py: 30 Hz to 1 kHz).
MIN_SUPPORTED_RATE_HZ = 30.0

CONTINUE, GAP, JUMP_BACK, NOT_INCREASING = "continue", "gap", "jump_back", "not_increasing"


@dataclass
class StampRule:
    """The jump rule of one stream (module docstring); `step(d_ns)` judges the next step.

    `fast_ns`: a step in (0, fast_ns] always continues (the node's hot path tests only
    that and calls `continued(d)`); others go through `step`.
    """

    max_gap_s: float = 0.0  # 0 = adaptive
    interval_ns: int = 0  # the stream's last step (> 0), 0 before its first step

    def __post_init__(self) -> None:
        if not self.max_gap_s >= 0.0:
            raise ValueError(f"max_stamp_gap must be >= 0 s (0 = adaptive), got {self.max_gap_s}")
        self.adaptive = self.max_gap_s == 0.0
        self.fast_ns = round((MIN_ADAPTIVE_GAP_S if self.adaptive else self.max_gap_s) * 1e9)

    def gap_ns(self) -> int:
        """G for the next step (module docstring)."""
        if not self.adaptive:
            return self.fast_ns
        if self.interval_ns == 0:
            return max(self.fast_ns, round(FIRST_STEP_MAX_S * 1e9))
        return max(self.fast_ns, GAP_PERIODS * self.interval_ns)

    def continued(self, d_ns: int) -> None:
        """A step in (0, fast_ns]: it continues; it is the stream's interval now."""
        self.interval_ns = d_ns

    def judge(self, d_ns: int) -> str:
        """CONTINUE, GAP, JUMP_BACK or NOT_INCREASING for a stamp step of d_ns (no change)."""
        g = self.gap_ns()
        if d_ns > 0:
            return GAP if d_ns > g else CONTINUE
        return JUMP_BACK if d_ns < -g else NOT_INCREASING

    def step(self, d_ns: int) -> str:
        """judge(d_ns), and a positive step (continued or a gap) becomes the stream's interval."""
        verdict = self.judge(d_ns)
        if d_ns > 0:
            self.interval_ns = d_ns
        return verdict

    def forget(self) -> None:
        """A new stream (e.g. a new recording): no interval known."""
        self.interval_ns = 0


def resets(stamps_ns, max_gap_s: float = 0.0) -> tuple[list[bool], list[bool]]:
    """(keep, reset) per sample of a recorded stream, as a node given it would judge it:
    `keep` False for a sample the node refuses (stamp <= 0, or not increasing); `reset`
    True where the estimator (re)starts (the first kept sample, gaps, jumps back)."""
    rule = StampRule(max_gap_s)
    keep, reset = [], []
    last = None
    for t in (int(x) for x in stamps_ns):
        if t <= 0:
            keep.append(False)
            reset.append(False)
            continue
        if last is None:
            keep.append(True)
            reset.append(True)
            last = t
            continue
        verdict = rule.step(t - last)
        if verdict == NOT_INCREASING:
            keep.append(False)
            reset.append(False)
            continue
        keep.append(True)
        reset.append(verdict != CONTINUE)
        last = t
    return keep, reset


def rate_note(interval_s: float) -> str | None:
    """One line when a stream at this interval is below the supported rates, else None."""
    if not interval_s > 0.0:
        return None
    rate = 1.0 / interval_s
    if rate >= MIN_SUPPORTED_RATE_HZ:
        return None
    return (f"input at {rate:.3g} Hz (stamp step {interval_s * 1e3:.1f} ms) is below the rates "
            f"the estimator is measured at ({MIN_SUPPORTED_RATE_HZ:g} Hz to 1 kHz, "
            "docs/estimation.md): torques are estimated all the same, with accelerations "
            "smoothed over a few samples of this stream (lag and error not measured here)")
