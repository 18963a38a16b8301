"""The torque node's live model, owned by one object: no ROS in here.

Two threads touch it, each through its own methods:

- the executor thread (the subscription and timer callbacks, parameter callbacks):
  `current()` per sample (the bundle to compute with; swaps in a newly built one between
  two samples), `first_output()` after a published output (the bundle to announce as
  applied from that output's stamp, once), `count("refused")`;
- the model builder thread (model_builder.py): `build()` (the next config id, the bundle),
  `built()` (makes it the newest: one reference assignment the executor picks up),
  `count("failed")`.

The counters are changed from both threads, so they sit behind one lock (a change of model
is rare: the lock is never on the per-sample path). The config texts are prepared on the
builder thread and read on both, also behind the lock. Everything else is one reference
written by one thread and read by the other.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable

from .torque_config import ModelBundle, ModelRequest

_PENDING = "__applies_from_stamp_ns__"  # placeholder in a prepared config text
COUNTERS = ("applied", "refused", "failed")


class LiveModel:
    """The bundle in use and the newest built, config ids, config texts, switch counters.

    make(request, config_id, n, previous) -> a new bundle (torque_config.build_bundle with the
    node's options), called on the builder thread. describe(bundle, applies_from) -> the
    whole config message (a dict) of `bundle`; it is called with a placeholder for
    applies_from, once per bundle, and the text is kept.
    """

    def __init__(self, first: ModelBundle,
                 make: Callable[[ModelRequest, int, int, ModelBundle], ModelBundle],
                 describe: Callable[[ModelBundle, object], dict]):
        self.in_use = first  # executor thread: what samples are computed with
        self._latest = first  # builder thread writes, executor thread reads (one reference)
        self._pending: ModelBundle | None = None  # in use, not yet stated with its stamp
        self._next_id = first.config_id + 1  # builder thread only
        self._make = make
        self._describe = describe
        self._lock = threading.Lock()
        self._counts = dict.fromkeys(COUNTERS, 0)
        self._texts: dict[int, str] = {}  # config_id -> text with the placeholder
        self._in_force = ""  # the text of the config in force (republished periodically)

    # -- executor thread -----------------------------------------------------------------
    def current(self) -> tuple[ModelBundle, bool]:
        """The bundle for the next sample, and True if it brings a new estimator (its
        history starts afresh). Per sample: one reference comparison unless a change came."""
        b = self._latest
        if b is self.in_use:
            return b, False
        fresh = b.estimator is not self.in_use.estimator
        self.in_use = b
        self._pending = b
        self.count("applied")
        return b, fresh

    @property
    def announcing(self) -> bool:
        """A bundle in use awaits the stamp of its first output."""
        return self._pending is not None

    def first_output(self) -> ModelBundle | None:
        """After an output computed with the bundle in use: that bundle if this was its first
        output (to be stated as applied from the output's stamp), else None."""
        b = self._pending
        if b is not None and b is self.in_use:
            self._pending = None
            return b
        return None

    # -- builder thread ------------------------------------------------------------------
    def build(self, request: ModelRequest) -> ModelBundle:
        """A bundle for `request` with the next config id (ValueError/TypeError if the core
        refuses or its joints differ); the running estimator carries on if unchanged."""
        latest = self._latest
        b = self._make(request, self._next_id, latest.arm.nv, latest)
        if b.arm.joint_names != latest.arm.joint_names:
            raise ValueError("its joint names differ from the running model's")
        self._next_id += 1
        return b

    def built(self, b: ModelBundle) -> None:
        """Make `b` the newest: the executor swaps it in before the next sample."""
        self._latest = b

    # -- either thread -------------------------------------------------------------------
    def count(self, what: str) -> None:
        with self._lock:
            self._counts[what] += 1

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def config_text(self, b: ModelBundle, applies_from: int | None) -> str:
        """The config message of `b`, applied from `applies_from` (a stamp; 0 = the start),
        or built and not applied yet (None). Prepared once per bundle; then one replace."""
        with self._lock:
            if applies_from is None or b.config_id not in self._texts:
                self._texts = {b.config_id: json.dumps(self._describe(b, _PENDING))}
            template = self._texts[b.config_id]
            text = template.replace(f'"{_PENDING}"', "null" if applies_from is None else str(applies_from))
            if applies_from is not None:
                self._in_force = text
            return text

    def restate(self) -> None:
        """Forget the prepared texts (what the node describes changed, e.g. its scheduling)."""
        with self._lock:
            self._texts = {}

    @property
    def in_force_text(self) -> str:
        """The config message in force ('' before the first was stated)."""
        return self._in_force
