"""Hostile streams for the onset trigger: robot grasp messages at odd moments must never turn
one interaction into two events, nor make the trigger deaf."""

from __future__ import annotations

from itertools import pairwise

import numpy as np

from runtime.trigger_settings import build_trigger, resolve_trigger

C = 234
PULL = [np.full(C, 1000)] * 40 + [np.full(C, 1000 + 40 * k) for k in range(1, 40)] + [np.full(C, 2600)] * 40
"""A settled grasp, then a person pulling (the pads' pressure ramps up over 1.2 s), then still."""


def _fires(rows, grasp: dict[int, bool] | None = None) -> list[int]:
    trigger = build_trigger(resolve_trigger(), (78, 78, 78), 4095.0, 15, 32.0)
    fires = []
    for i, row in enumerate(rows):
        if grasp and i in grasp:
            trigger.set_grasp(grasp[i])
        if trigger.update(np.asarray(row, dtype=np.uint16), i) >= 0:
            fires.append(i)
    return fires


def test_a_pull_fires_once():
    assert len(_fires(PULL)) == 1


def test_grasp_closed_during_the_pull_it_fired_on_is_not_a_second_event():
    first = _fires(PULL)[0]
    for late in (1, 2, 5):
        assert _fires(PULL, {first + late: True}) == [first]
    assert _fires(PULL, {first + 2: True, first + 3: False, first + 4: True}) == [first]


def test_random_walks_with_random_grasp_messages_never_fire_twice_within_the_refractory_time():
    refractory = build_trigger(resolve_trigger(), (78, 78, 78), 4095.0, 15, 32.0).refractory_frames
    for seed in range(60):
        rng = np.random.default_rng(seed)
        level, rows, grasp = rng.uniform(0, 4095), [], {}
        for i in range(400):
            level = float(np.clip(level + rng.normal(0, rng.choice([1, 50, 800])), 0, 4095))
            rows.append(np.full(C, level))
            if rng.random() < 0.05:
                grasp[i] = bool(rng.random() < 0.7)
        fires = _fires(rows, grasp)
        assert all(b - a >= refractory for a, b in pairwise(fires)), (seed, fires)


def test_grasp_closed_repeated_every_frame_does_not_make_the_trigger_deaf():
    """A robot that repeats its state (``grasp closed`` at its control rate) must not re-baseline
    the armed trigger on every frame: the person's pull would never depart from the baseline."""
    assert len(_fires(PULL, {i: True for i in range(30, len(PULL))})) == 1
