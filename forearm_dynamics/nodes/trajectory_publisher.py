"""trajectory_publisher: replay library movements as JointState at rate_hz (default 1 kHz).

Each sample is stamped with the ROS clock at publication and q, qd are the movement
evaluated at exactly that stamp (t = stamp - t0, t0 = stamp of the movement's first
sample), so position and velocity agree with the stamp; samples are therefore not exactly
1/rate apart, and that is fine. A movement has round(duration * rate_hz) samples on the
nominal grid t0 + k/rate_hz; a timer tick publishes every sample that is due (normally
one), so a late tick is caught up (at most MAX_BURST samples) instead of losing samples.

At each movement start a JSON marker goes out on `movement` (reliable, transient local,
depth 100): id, name, elbow, body_size, t0 (s) and t0_ns of its first sample. Without
`loop`, the node waits until subscribers acknowledged everything (up to `drain` s) and
exits 0; stopped by SIGINT/SIGTERM, it waits the same way before it exits. Parameters:
config/nodes/trajectory_publisher.yaml; an invalid one -> exit code 2.

Sensor-like input (noise_deg, publish_velocity, jitter_ms, drop_fraction, seed): with the
defaults the stream is exact as above. Otherwise, per due sample and in this order from
one numpy Generator seeded with `seed` (the same seed and settings give the same draws):
the sample is dropped with probability drop_fraction (not published; the next due sample
is evaluated at its own stamp); the stamp is the clock plus a uniform offset in
[-jitter_ms, +jitter_ms] (kept 1 us after the previous stamp, and q, qd are evaluated at
that stamp, so the truth stays movement.evaluate(stamp - t0)); Gaussian noise of std
noise_deg is added to every position; velocities are left out when publish_velocity is
false. The settings are in every marker (key "sensor"), so check_bag knows the input was
noisy and scores the torques against the noiseless truth.

Hot path (every sample; its cost is part of the pipeline's stamp-to-torque latency): the
minimum-jerk sample is evaluated with Python floats and three numpy calls written straight
into a preallocated CDR message (jointstate_cdr.OutputTemplate), which is published raw;
the result equals Movement.evaluate bit for bit (same operations in the same order).
Before: Movement.evaluate (~25 numpy calls, ~17 us) and rclpy's message conversion.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from ..anthropometry import resolve_body_size
from ..codec.jointstate_cdr import OutputTemplate
from ..description import JOINT_NAMES
from ..exit_codes import OK
from ..movements import Movement, get_movement, movement_library
from ..shoulder import CONVENTIONS, SHOULDER_CHOICES, synthetic_shoulder_motion
from .common import EXECUTORS, MATCH_POLL_S, MatchLog, latched_qos, main_for, stream_qos
from .params import ParameterError, Params, Spec, init_node

#: Samples one late tick may catch up (0.5 s at 1 kHz, within the default depth of 1000);
#: beyond that they are skipped with a warning. A ~0.3 s stall of the process was seen.
MAX_BURST = 500

SPECS = (
    Spec("movements", list(range(1, 66)), "movement ids in replay order; default all 65", "", 1,
         len(movement_library())),
    Spec("body_size", 50, "ANSUR II percentile 5, 50 or 95, recorded in the markers (the "
         "angles do not depend on it)"),
    Spec("rate_hz", 1000.0, "samples per second", "Hz", 1e-3, 10000.0),
    Spec("loop", False, "replay the list forever (false: drain, then exit 0)"),
    Spec("start_delay", 5.0, "wait before the first sample (discovery settles; see the YAML)",
         "s", 0.0, 3600.0),
    Spec("subscriber_timeout", 10.0, "wait this long for joint_states subscribers, then start "
         "anyway", "s", 0.0, 3600.0),
    Spec("min_subscribers", 1, "subscribers to wait for (2 with torque_node + bag_recorder)",
         "", 0, 1000),
    Spec("gap", 0.0, "silence between movements", "s", 0.0, 3600.0),
    Spec("drain", 2.0, "wait at the end (or when stopped) for subscribers to acknowledge everything",
         "s", 0.0, 600.0),
    Spec("output_topic", "joint_states", "JointState output topic"),
    Spec("marker_topic", "movement", "topic of the JSON marker sent at each movement start"),
    Spec("qos_depth", 1000, "history depth of the JointState stream (1000 = 1 s at 1 kHz)",
         "messages", 1, 100000),
    Spec("qos_reliable", True, "reliable (true) or best-effort (false) stream"),
    Spec("executor", "events", "rclpy executor: events or single", choices=EXECUTORS),
    Spec("noise_deg", 0.0, "std of Gaussian noise added to every position (a simulated sensor); "
         "0 = exact", "deg", 0.0, 90.0),
    Spec("publish_velocity", True, "publish velocities (false: positions only, like motion capture)"),
    Spec("jitter_ms", 0.0, "stamp jitter: uniform in +-jitter_ms around the clock", "ms", 0.0, 1000.0),
    Spec("drop_fraction", 0.0, "probability that a sample is not published", "", 0.0, 0.9),
    Spec("shoulder", "none", "also publish a synthetic shoulder motion (shoulder.SYNTHETIC: sines in "
         "that convention's public names, after the 20 joints) for a torque_node with the same "
         "shoulder; none = the 20 joints only", choices=SHOULDER_CHOICES),
    Spec("seed", 0, "seed of the noise, jitter and drop draws (same seed: same stream)", "", 0,
         2**62),
)


@dataclass(frozen=True)
class ReplaySettings:
    """The validated parameters of one replay."""

    movements: tuple[Movement, ...]
    body_size: int
    rate_hz: float
    loop: bool
    start_delay: float
    subscriber_timeout: float
    min_subscribers: int
    gap: float
    drain: float
    output_topic: str
    marker_topic: str
    qos_depth: int
    qos_reliable: bool
    executor: str
    noise_deg: float = 0.0
    publish_velocity: bool = True
    jitter_ms: float = 0.0
    drop_fraction: float = 0.0
    seed: int = 0
    shoulder: str = "none"

    @property
    def exact(self) -> bool:
        """The analytic stream (no sensor simulation)."""
        return (self.noise_deg == 0.0 and self.publish_velocity and self.jitter_ms == 0.0
                and self.drop_fraction == 0.0)

    def sensor(self) -> dict:
        """The sensor settings as stated in each marker."""
        return {"noise_deg": self.noise_deg, "publish_velocity": self.publish_velocity,
                "jitter_ms": self.jitter_ms, "drop_fraction": self.drop_fraction, "seed": self.seed}

    @classmethod
    def from_params(cls, p: Params) -> ReplaySettings:
        ids = p.value("movements")
        body_size = p.value("body_size")
        try:
            resolve_body_size(body_size)
        except ValueError as exc:
            raise ParameterError("body_size", str(exc)) from None
        settings = cls(
            movements=tuple(get_movement(i) for i in ids),
            body_size=body_size,
            rate_hz=p.value("rate_hz"),
            loop=p.value("loop"),
            start_delay=p.value("start_delay"),
            subscriber_timeout=p.value("subscriber_timeout"),
            min_subscribers=p.value("min_subscribers"),
            gap=p.value("gap"),
            drain=p.value("drain"),
            output_topic=p.topic("output_topic"),
            marker_topic=p.topic("marker_topic"),
            qos_depth=p.value("qos_depth"),
            qos_reliable=p.value("qos_reliable"),
            executor=p.value("executor"),
            noise_deg=p.value("noise_deg"),
            publish_velocity=p.value("publish_velocity"),
            jitter_ms=p.value("jitter_ms"),
            drop_fraction=p.value("drop_fraction"),
            seed=p.value("seed"),
            shoulder=p.value("shoulder"),
        )
        p.distinct_topics(("output_topic", "marker_topic"))  # two types on one topic: rcl error
        return settings


def marker_qos() -> QoSProfile:
    """Reliable and transient local: a recorder that joins late still gets the markers."""
    return latched_qos(depth=100)


class TrajectoryPublisher(Node):
    """Timer-driven replay: waiting -> (movement, gap)* -> drain -> done."""

    def __init__(self, node_name: str = "trajectory_publisher"):
        init_node(self, node_name)
        self.params = Params(self, SPECS, "trajectory_publisher")
        s = self.settings = ReplaySettings.from_params(self.params)
        self.params.warn_unknown()
        self.executor_kind = s.executor
        self.done = Future()
        self.exit_code = OK

        # raw JointState, effort empty (and velocity too for a positions-only sensor)
        extra = () if s.shoulder == "none" else CONVENTIONS[s.shoulder].joint_names
        self.out = OutputTemplate((*JOINT_NAMES, *extra), effort=False, velocity=s.publish_velocity)
        n = len(JOINT_NAMES)
        self._q = self.out.q[:n]  # the 20 joints; the shoulder's after them (views)
        self._qd = self.out.qd[:n] if s.publish_velocity else np.zeros(n)
        self._rng = np.random.default_rng(s.seed)
        self._noise = np.zeros(len(JOINT_NAMES))
        self._noise_rad = float(np.radians(s.noise_deg))
        self._jitter_ns = round(s.jitter_ms * 1e6)
        self._last_stamp = 0
        self.dropped = 0
        self.pub = self.create_publisher(
            JointState, s.output_topic, stream_qos(s.qos_depth, s.qos_reliable)
        )
        self.marker_pub = self.create_publisher(String, s.marker_topic, marker_qos())

        self._period_ns = round(1e9 / s.rate_hz)
        # set at the first tick: with use_sim_time the clock reads 0 until the first /clock,
        # and a wait measured from 0 was over at once ("0 of 1 subscribers after 1.8e9 s;
        # publishing anyway": the closed-loop example lost its first movement)
        self._started_ns: int | None = None
        self._playing = False
        self._index = -1  # position in the playlist
        self.movement: Movement = s.movements[0]  # the one playing (or last played)
        self._next_start_ns: int | None = None  # when the next movement is due
        self._k = 0  # next sample of the current movement
        self._n = 0  # samples in the current movement
        self._t0_ns = 0
        self.sent = 0
        self.skipped = 0
        self.timer = self.create_timer(1.0 / s.rate_hz, self._tick)
        # the writer's own count of readers, logged on each change (common.MatchLog): the
        # side of a match a reader's log cannot show (docs/reliability.md, restarts)
        topic = self.pub.topic_name
        self.create_timer(MATCH_POLL_S, MatchLog(
            self, self.pub.get_subscription_count,
            lambda n: f"{topic}: matched by {n} subscriber(s)"))
        total = sum(m.duration for m in s.movements)
        self.get_logger().info(
            f"{len(s.movements)} movement(s), {total:.1f} s at {s.rate_hz:g} Hz on "
            f"{self.pub.topic_name}{' (looping)' if s.loop else ''}"
            + ("" if s.exact else f"; simulated sensor {s.sensor()}")
        )

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    # -- state machine -------------------------------------------------------------------
    def _tick(self) -> None:
        now = self._now_ns()
        if self._next_start_ns is None and not self._playing:
            if not self._ready(now):
                return
            self._next_start_ns = now
        half = self._period_ns // 2
        if not self._playing:
            if now + half < self._next_start_ns:
                return
            if not self._advance():
                self._finish()
                return
        due = min(self._n, (now - self._t0_ns + half) // self._period_ns + 1) if self._k else 1
        if due - self._k > MAX_BURST:
            self.skipped += due - self._k - MAX_BURST
            self.get_logger().warning(
                f"timer {(due - self._k) / self.settings.rate_hz * 1e3:.0f} ms late: "
                f"skipping {due - self._k - MAX_BURST} samples", throttle_duration_sec=1.0
            )
            self._k = due - MAX_BURST
        while self._k < due:
            self._publish_sample()
        if self._k >= self._n:
            self._playing = False
            self._next_start_ns = self._t0_ns + self._n * self._period_ns + round(
                self.settings.gap * 1e9
            )

    def _ready(self, now: int) -> bool:
        """Start delay over and enough subscribers present (or the wait for them timed out)."""
        s = self.settings
        if self._started_ns is None:
            self._started_ns = now
        waited = (now - self._started_ns) * 1e-9
        if waited < s.start_delay:
            return False
        count = self.pub.get_subscription_count()
        if count >= s.min_subscribers:
            return True
        if waited < s.start_delay + s.subscriber_timeout:
            return False
        self.get_logger().warning(
            f"{count} of {s.min_subscribers} subscribers on {self.pub.topic_name} after "
            f"{waited:.1f} s; publishing anyway"
        )
        return True

    def _advance(self) -> bool:
        """Move to the next movement of the playlist; False when the replay is over."""
        self._index += 1
        movements = self.settings.movements
        if self._index >= len(movements):
            if not self.settings.loop:
                return False
            self._index = 0
        self.movement = m = movements[self._index]
        self._shape = (m.start, m.stop - m.start, m.hold_before, m.transition)
        self._n = max(1, round(self.movement.duration * self.settings.rate_hz))
        self._k = 0
        self._playing = True
        return True

    def _publish_sample(self) -> None:
        t_ns = self.get_clock().now().nanoseconds
        s = self.settings
        if not s.exact:
            if self._k and s.drop_fraction and self._rng.random() < s.drop_fraction:
                self._k += 1  # the first sample (the marker's t0) is never dropped
                self.dropped += 1
                return
            if self._jitter_ns and self._k:
                t_ns += int(self._rng.integers(-self._jitter_ns, self._jitter_ns, endpoint=True))
            t_ns = max(t_ns, self._last_stamp + 1000)
        self._last_stamp = t_ns
        if self._k == 0:
            self._t0_ns = t_ns
            self._publish_marker(t_ns)
        # Movement.evaluate at one time, same operations (movements.min_jerk), no arrays
        start, delta, hold, transition = self._shape
        t = ((t_ns - self._t0_ns) / 1e9 - hold) / transition
        t = min(max(t, 0.0), 1.0)  # np.clip(t, 0, 1)
        t2 = t * t
        s = t2 * t * (10.0 - 15.0 * t + 6.0 * t2)
        ds = 30.0 * t2 * (1.0 - 2.0 * t + t2)
        q = np.multiply(delta, s, out=self._q)
        q += start
        np.multiply(delta, ds / transition, out=self._qd)
        cfg = self.settings
        if cfg.shoulder != "none":  # the synthetic shoulder motion, from the movement's start
            sq, sqd, _ = synthetic_shoulder_motion(cfg.shoulder, (t_ns - self._t0_ns) / 1e9)
            self.out.q[20:] = sq[0]
            if cfg.publish_velocity:
                self.out.qd[20:] = sqd[0]
        if self._noise_rad:
            self._rng.standard_normal(out=self._noise)
            self._noise *= self._noise_rad
            q += self._noise
        out = self.out
        out.pack_stamp(*divmod(t_ns, 1_000_000_000))
        self.pub.publish(out.payload())
        self._k += 1
        self.sent += 1

    def _publish_marker(self, t0_ns: int) -> None:
        m = self.movement
        info = {
            "id": m.id,
            "name": m.name,
            "elbow": m.elbow,
            "body_size": self.settings.body_size,
            "t0_ns": t0_ns,
            "t0": t0_ns / 1e9,
            "duration": m.duration,
            "samples": self._n,
            "rate_hz": self.settings.rate_hz,
            "index": self._index,
            "sensor": self.settings.sensor(),
        }
        self.marker_pub.publish(String(data=json.dumps(info)))
        self.get_logger().info(f"movement {m.id} ({m.name}, {m.elbow})")

    def _finish(self) -> None:
        """Stop the timer, let reliable subscribers acknowledge, then end the spin."""
        self._stop_and_drain("done")
        self.done.set_result(True)

    def settle_on_stop(self) -> None:
        """Stopped by SIGINT/SIGTERM (run() calls this before the context goes): what was
        sent still reaches reliable subscribers, up to `drain` s. A reliable sample a slow
        reader's buffer dropped is repaired by the writer, and only while the writer lives:
        a publisher stopped right after sending lost its last samples to a node starved at
        that moment (its answer never came; test_faults_process under a second make test)."""
        if not self.done.done():  # else finished (and drained) before the stop
            self._stop_and_drain("stopped")

    def _stop_and_drain(self, verb: str) -> None:
        """No more samples; wait up to `drain` s for reliable subscribers' acknowledgements;
        say what was sent."""
        self.timer.cancel()
        drain = Duration(nanoseconds=round(self.settings.drain * 1e9))
        acked = all(p.wait_for_all_acked(drain) for p in (self.pub, self.marker_pub))
        self.get_logger().info(
            f"{verb}: {self.sent} samples, {self.skipped} skipped, {self.dropped} dropped"
            + ("" if acked else f"; not all acknowledged within {self.settings.drain:g} s")
        )


def main() -> None:
    main_for(TrajectoryPublisher, "trajectory_publisher")


if __name__ == "__main__":
    main()

