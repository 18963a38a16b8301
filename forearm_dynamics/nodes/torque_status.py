"""What torque_node states about itself: the config message on `~/config` (model, body
size, side, payload, estimator and its lag, input handling, σ, scheduling; config_id and
applies_from_stamp_ns) and its /diagnostics values (rate, units checks, live changes,
timer skips).

A mixin of TorqueNode (and so of the lifecycle node, which adds its state to both).
"""

from __future__ import annotations

from std_msgs.msg import String

from ..estimation.stamps import MIN_SUPPORTED_RATE_HZ, rate_note
from ..model_config import config_message
from .torque_config import ModelBundle


class TorqueStatus:
    """config_message / diagnostic_values hooks and the latched config's republishing."""

    def config_message(self, b: ModelBundle, applies_from: int | None) -> dict:
        dt = self.sample_interval_s()
        s = self.settings
        return config_message(
            b.model_config,
            config_id=b.config_id,
            applies_from_stamp_ns=applies_from,
            node=self.get_fully_qualified_name(),
            version=self._version,
            estimator=b.estimator.describe(dt, self._velocity_given),
            input_topic=self.sub.topic_name if hasattr(self, "sub") else s.input_topic,
            output_topic=self.pub.topic_name if hasattr(self, "pub") else s.output_topic,
            max_stamp_gap=s.max_stamp_gap,
            output_rate_hz=self.output_rate_hz,
            input_timeout=self.input_timeout_ns / 1e9,
            build_ms=round(b.build_ms, 3),
            deadline_ms=self.deadlines.deadline_ms if hasattr(self, "deadlines") else None,
            realtime=(self.realtime_state.describe() if self.realtime_state is not None
                      else {"policy": "not applied yet"}),
            std=self._std_config(b),
            input=self._input_config(),
        )

    def _input_config(self) -> dict:
        out = {"missing_joints": self.missing_joints,
               "held_joints": list(getattr(self, "held_joints", ())),
               "queue_depth": self.settings.qos_depth}  # check_bag: was a loss an overflow?
        if self._hold_posture is not None:
            out["hold_posture"] = dict(zip(self.live.in_use.arm.joint_names if hasattr(self, "live")
                                           else (), self._hold_posture.tolist(), strict=False))
        return out

    def _std_config(self, b: ModelBundle) -> dict:
        if self._std_topic is None:
            return {"published": False, "why": "publish_std is false"}
        out = dict(b.std_config)
        if out.get("published") and hasattr(self, "std_pub"):
            out["topic"] = self.std_pub.topic_name  # as resolved (remapping included)
        return out

    def _publish_config(self, b: ModelBundle, applies_from: int | None) -> None:
        """State `b`: applied from `applies_from` (a stamp; 0 = the start), or built (None)."""
        self.config_pub.publish(String(data=self.live.config_text(b, applies_from)))

    def on_first_step(self, d_ns: int) -> None:
        """The input's rate is known: one line if it is below the supported rates."""
        note = rate_note(d_ns * 1e-9)
        if note is not None:
            self.get_logger().warning(note)

    def diagnostic_values(self, status) -> dict[str, str]:
        b = self.live.in_use
        dt = self.stamp_rule.interval_ns * 1e-9
        rate = {"stamp_rate_hz": f"{1.0 / dt:.3g}" if dt > 0 else "unknown",
                "rate_supported": "unknown" if dt <= 0 else
                ("yes" if rate_note(dt) is None else f"no: below {MIN_SUPPORTED_RATE_HZ:g} Hz")}
        if dt > 0 and rate_note(dt) is not None and status.level == status.OK \
                and status.message != "no input":  # a stream's last step may be its pause
            status.level = status.WARN
            status.message = (f"input at {1.0 / dt:.3g} Hz: below the rates the estimator is "
                              f"measured at ({MIN_SUPPORTED_RATE_HZ:g} Hz to 1 kHz)")
        desc = b.estimator.describe(self.sample_interval_s(), self._velocity_given)
        extra = {
            "config_id": str(b.config_id),
            "model": f"{b.arm.kind}, body size {b.arm.body_size.label}",
            "estimator": desc["method"],
            **{f"estimator.lag_{k}_s": f"{x:.6f}" for k, x in desc["lag_s"].items()},
            "estimator.noise_rad": "unknown" if desc["noise_rad"] is None else f"{desc['noise_rad']:.3g}",
            "missing_joints": self.missing_joints,
            "held_joints": ", ".join(self.held_joints) or "none",
            **{f"live_changes.{k}": str(n) for k, n in self.live.counts().items()},
            **rate,
        }
        guard = self._guard
        if guard.far_count > self._far_seen:
            status.level = status.ERROR
            status.message = (f"{guard.far_count - self._far_seen} sample(s) with angles far outside "
                              "the joints' ranges: check units (degrees as radians?)")
            self._far_seen = guard.far_count
        elif guard.tiny_warning:
            status.level = max(status.level, status.WARN)
            status.message = "angles all within +-3 deg while moving: check units (radians twice?)"
        extra["angles_far_out_of_range"] = str(guard.far_count)
        extra["angles_warned"] = ", ".join(sorted(guard.warned)) or "none"
        if self.output_rate_hz > 0:
            extra.update({f"timer_skipped.{k}": str(n) for k, n in self.timer_skipped.items()})
            if self._silent in ("input_timeout", "stamps_behind"):
                status.level = status.WARN
                status.message = f"not publishing: {self._silent.replace('_', ' ')}"
        return extra

    def after_diagnostics(self) -> None:
        if self.held_joints != self._held_stated:  # the input's joint set changed: restate
            self._held_stated = self.held_joints
            self.live.restate()
            self._publish_config(self.live.in_use, 0)
        self._after_diagnostics_base()

    def _after_diagnostics_base(self) -> None:
        text = self.live.in_force_text  # the config in force, republished with the diagnostics
        if text:
            self.config_pub.publish(String(data=text))
