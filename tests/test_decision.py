"""Continuous mode's report rule (runtime/decision.py) on hand-made label and score sequences."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.decision import ContinuousDecision, margin_of

D, PULL, PUSH, HOLD, BUMP = 0, 1, 2, 3, 4  # class indices; 0 is dormant here


def _scores(label: int, margin: float) -> np.ndarray:
    row = np.zeros(5, np.float32)
    row[label] = 4.0
    row[(label + 1) % 5] = 4.0 - margin
    return row


def _reports(rule: ContinuousDecision, labels, margins=None) -> list[tuple[int, int]]:
    out = []
    for i, k in enumerate(labels):
        scores = _scores(k, 1.0 if margins is None else margins[i])
        r = rule.update(k, scores)
        if r >= 0:
            out.append((i, r))
    return out


def test_plain_rule_reports_every_change_to_a_non_dormant_class():
    rule = ContinuousDecision(5, D)  # confirm 1, no margin, rearm 0
    labels = [D, PULL, PULL, PUSH, PULL, D, PULL, BUMP]
    assert _reports(rule, labels) == [(1, PULL), (3, PUSH), (4, PULL), (6, PULL), (7, BUMP)]


def test_confirm_needs_n_consecutive_wins():
    rule = ContinuousDecision(5, D, confirm_frames=3)
    labels = [PULL, PULL, BUMP, PULL, PULL, PULL, PULL, D, HOLD, HOLD, HOLD]
    assert _reports(rule, labels) == [(5, PULL), (10, HOLD)]


def test_dormant_breaks_a_run():
    rule = ContinuousDecision(5, D, confirm_frames=2)
    assert _reports(rule, [PUSH, D, PUSH, D, PUSH, PUSH]) == [(5, PUSH)]


def test_margin_below_the_minimum_breaks_the_run():
    rule = ContinuousDecision(5, D, confirm_frames=2, min_margin=0.5)
    labels = [PULL, PULL, D, BUMP, BUMP, BUMP]
    margins = [0.6, 0.4, 1.0, 0.7, 0.2, 0.9]
    assert _reports(rule, labels, margins) == []
    assert _reports(ContinuousDecision(5, D, 2, 0.5), [BUMP, BUMP], [0.5, 0.8]) == [(1, BUMP)]


def test_one_report_per_interaction_and_rearm_after_m_dormant_frames():
    rule = ContinuousDecision(5, D, confirm_frames=2, rearm_frames=3)
    labels = [PULL, PULL,  # reported
              BUMP, BUMP, PULL, PULL,  # same interaction: flicker, not reported
              D, D, PUSH, PUSH,  # two dormant frames are not enough to re-arm
              D, D, D,  # re-armed
              PULL, PULL]  # a new interaction
    assert _reports(rule, labels) == [(1, PULL), (14, PULL)]


def test_reset_rearms_and_forgets_the_run():
    rule = ContinuousDecision(5, D, confirm_frames=2, rearm_frames=50)
    assert _reports(rule, [HOLD, HOLD]) == [(1, HOLD)]
    assert rule.update(PUSH, _scores(PUSH, 1)) == -1 and not rule.armed
    rule.reset()
    assert rule.armed and rule.update(PUSH, _scores(PUSH, 1)) == -1
    assert rule.update(PUSH, _scores(PUSH, 1)) == PUSH


def test_margin_is_winner_minus_runner_up_and_leaves_the_scores_alone():
    row = np.array([0.2, 3.3, 1.1, 2.9, -0.5], np.float32)
    before = row.copy()
    assert margin_of(row, 1) == pytest.approx(0.4, abs=1e-6)
    assert margin_of(row, 3) == pytest.approx(-0.4, abs=1e-6)
    np.testing.assert_array_equal(row, before)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"dormant": 5}, "dormant"), ({"confirm_frames": 0}, "confirm_frames"),
    ({"min_margin": -1.0}, "min_margin"), ({"rearm_frames": -1}, "rearm_frames"),
])
def test_bad_parameters_are_refused(kwargs, message):
    args = {"n_classes": 5, "dormant": D, **kwargs}
    with pytest.raises(ValueError, match=message):
        ContinuousDecision(**args)


def test_a_hold_that_flickers_with_dormant_is_confirmed_when_short_gaps_do_not_break_the_run():
    flicker = [HOLD, D, HOLD, HOLD, D, HOLD, HOLD, D, HOLD, HOLD] + [D] * 10
    assert _reports(ContinuousDecision(5, D, confirm_frames=4, rearm_frames=4), flicker) == []
    assert _reports(ContinuousDecision(5, D, confirm_frames=4, rearm_frames=4, gap_frames=1), flicker) == [(5, HOLD)]
    two_gap = [HOLD, HOLD, D, D, HOLD, HOLD]
    assert _reports(ContinuousDecision(5, D, confirm_frames=4, gap_frames=1), two_gap) == []


def test_vote_reports_the_class_that_won_most_frames_of_a_run_of_any_non_dormant_class():
    flicker = [PULL, PUSH, PULL, PUSH, PULL, PULL, D, D, D, D]
    assert _reports(ContinuousDecision(5, D, confirm_frames=3, rearm_frames=2), flicker) == []
    assert _reports(ContinuousDecision(5, D, confirm_frames=5, rearm_frames=2, vote=True), flicker) == [(4, PULL)]


def _confirmed_at(labels, margins, confirm: int, min_margin: float) -> list[int]:
    """Frames where a non-dormant class completes ``confirm`` wins in a row, each with the margin."""
    out, run = [], 0
    for i, k in enumerate(labels):
        ok = k != D and margins[i] >= min_margin
        run = run + 1 if ok and run and labels[i - 1] == k else int(ok)
        if run == confirm:
            out.append(i)
    return out


def _longest_dormant(labels) -> int:
    best = run = 0
    for k in labels:
        run = run + 1 if k == D else 0
        best = max(best, run)
    return best


def test_gap_and_vote_off_is_the_rule_as_documented():
    """With the defaults, a confirmed class is reported unless no interaction ended since the last report."""
    rng = np.random.default_rng(3)
    labels = rng.choice([D, D, D, PULL, PUSH, HOLD, BUMP], size=2000).tolist()
    margins = rng.uniform(0, 2, size=2000)
    for confirm, margin, rearm in ((1, 0.0, 0), (2, 0.5, 0), (3, 0.5, 4), (2, 0.0, 1)):
        expected, last = [], -1
        for i in _confirmed_at(labels, margins, confirm, margin):
            gap = _longest_dormant(labels[last + 1:i])
            ended = gap >= rearm if rearm else gap > 0 or labels[i] != labels[last]
            if last < 0 or ended:
                expected.append((i, labels[i]))
                last = i
        assert len(expected) > 5
        assert _reports(ContinuousDecision(5, D, confirm, margin, rearm), labels, margins) == expected
