"""False events per hour carry their exact Poisson interval, and a short idle recording says what one
event weighs (trainer/rate_interval.py, trainer/own_replay.py)."""

from __future__ import annotations

import math

import pytest

from trainer.own_replay import SHORT_IDLE_MIN, replay_lines
from trainer.rate_interval import poisson_interval, proportion_interval, rate_interval


@pytest.mark.parametrize(("count", "lower", "upper"), [
    (0, 0.0, 3.689), (1, 0.0253, 5.572), (5, 1.623, 11.668), (10, 4.795, 18.390), (100, 81.364, 121.627),
])
def test_the_interval_matches_the_tabulated_exact_bounds(count, lower, upper):
    lo, hi = poisson_interval(count)
    assert math.isclose(lo, lower, abs_tol=5e-4) and math.isclose(hi, upper, abs_tol=5e-4)


def test_a_rate_interval_is_the_count_interval_per_hour_and_none_without_time():
    lo, hi = rate_interval(5, 0.5)
    assert math.isclose(lo, 2 * 1.6235, abs_tol=1e-3) and math.isclose(hi, 2 * 11.6683, abs_tol=1e-3)
    assert rate_interval(0, 0.0) is None
    with pytest.raises(ValueError):
        poisson_interval(-1)


@pytest.mark.parametrize(("count", "n", "lower", "upper"), [
    (0, 10, 0.0, 0.3085), (22, 25, 0.6878, 0.9745), (45, 50, 0.7819, 0.9667), (10, 10, 0.6915, 1.0),
])
def test_a_share_has_the_exact_clopper_pearson_bounds(count, n, lower, upper):
    lo, hi = proportion_interval(count, n)
    assert math.isclose(lo, lower, abs_tol=5e-4) and math.isclose(hi, upper, abs_tol=5e-4)


@pytest.mark.parametrize(("count", "n"), [(3, 2), (0, 0), (-1, 5), (2.5, 5)])
def test_a_share_of_an_impossible_count_is_refused(count, n):
    with pytest.raises(ValueError):
        proportion_interval(count, n)


def _replay(false_events: int, minutes: float) -> dict:
    hours = minutes / 60
    return {"folds": [{}], "reference": ["onset"], "events": 0, "idle_hours": hours, "false_events": false_events,
            "false_per_hour": false_events / hours, "idle_by_source": {"quiet": {"hours": hours, "false_events": false_events}}}


def test_replay_lines_give_the_interval_and_say_when_the_idle_is_short():
    lines = replay_lines(_replay(3, 9.6))
    lo, hi = rate_interval(3, 9.6 / 60)
    assert lines[0].startswith(f"idle: false events 18.8/h (3 in 0.16 h), 95 % interval {lo:.1f}-{hi:.1f}/h (9.6 min: ")
    assert lines[1] == ("9.6 min of idle: one false event is 6.2 per hour; record more idle "
                        "(`handover record --device URL --idle-only --idle-minutes 20 --subject ID --out DIR`) for a tighter figure")
    long = replay_lines(_replay(3, SHORT_IDLE_MIN + 1))
    assert len(long) == 2 and "95 % interval" in long[0] and long[1].startswith("real idle signals: none")


def test_a_rate_is_written_with_its_count_and_hours():
    from runtime.event_rate import rate_text

    assert rate_text(4, 0.16066) == "24.9/h (4 in 0.16 h)"  # results/streams_own.md's held-out replay
    assert rate_text(1, 2.16, 2) == "0.46/h (1 in 2.16 h)"
    assert rate_text(0, 0.8 / 60) == "0.0/h (0 in 0.013 h)"
    assert rate_text(3, 0.0) == rate_text(3, None) == "-/h (none observed)"
