"""The torque node's live model (nodes/live_model.py) on its own, no ROS: what the executor
thread sees per sample while a builder thread builds, the first-output announcement, the
config texts, and the counters both threads change."""

from __future__ import annotations

import json
import threading

import pytest

from forearm_dynamics.nodes.live_model import LiveModel
from forearm_dynamics.nodes.torque_config import LIVE, MODEL_SPECS, ModelRequest, build_bundle

pytestmark = pytest.mark.unit

DEFAULTS = {s.name: s.default for s in MODEL_SPECS if s.name in LIVE}


def _request(**changes) -> ModelRequest:
    return ModelRequest.from_values({**DEFAULTS, **changes})


def _live() -> LiveModel:
    first = build_bundle(_request(), 1, 20)
    return LiveModel(first, build_bundle,
                     lambda b, applies: {"config_id": b.config_id, "applies_from_stamp_ns": applies})


def test_a_built_model_is_swapped_in_at_the_next_sample_and_announced_once() -> None:
    live = _live()
    first, fresh = live.current()
    assert first.config_id == 1 and not fresh and not live.announcing
    b = live.build(_request(body_size=95))  # same estimator settings: the estimator carries on
    assert b.config_id == 2 and live.current()[0] is first  # built, not handed over yet
    live.built(b)
    assert live.current() == (b, False) and live.in_use is b and live.announcing
    assert live.first_output() is b and live.first_output() is None and not live.announcing
    c = live.build(_request(estimator="backward"))
    live.built(c)
    assert live.current() == (c, True)  # a new estimator: its history starts afresh
    assert live.counts() == {"applied": 2, "refused": 0, "failed": 0}


def test_a_refused_build_changes_nothing() -> None:
    calls = []

    def make(request, config_id, n, previous):
        calls.append(config_id)
        if len(calls) == 1:
            raise ValueError("the core refuses")
        return build_bundle(request, config_id, n, previous)

    first = build_bundle(_request(), 1, 20)
    live = LiveModel(first, make, lambda b, applies: {})
    with pytest.raises(ValueError, match="refuses"):
        live.build(_request(side="left"))
    assert live.current() == (first, False)
    assert live.build(_request(side="left")).config_id == 2  # the refused one took no id
    assert calls == [2, 2]


def test_config_texts_are_prepared_once_and_applied_by_replacement() -> None:
    live = _live()
    b = live.in_use
    assert json.loads(live.config_text(b, None))["applies_from_stamp_ns"] is None
    assert live.in_force_text == ""
    assert json.loads(live.config_text(b, 1234))["applies_from_stamp_ns"] == 1234
    assert json.loads(live.in_force_text) == {"config_id": 1, "applies_from_stamp_ns": 1234}


def test_counters_changed_from_two_threads_lose_nothing() -> None:
    live = _live()
    n = 20000

    def refuse() -> None:
        for _ in range(n):
            live.count("refused")

    t = threading.Thread(target=refuse)
    t.start()
    for _ in range(n):
        live.count("failed")
    t.join()
    assert live.counts() == {"applied": 0, "refused": n, "failed": n}
