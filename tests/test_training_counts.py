"""The training counts a model's metadata carries, read back from hand-edited or damaged metadata:
the inspect card words them, so a value that is no count, or counts that contradict each other, must
read as not recorded, never crash it nor print a negative number of windows."""

from __future__ import annotations

import pytest

from runtime.training_counts import TrainingCounts

GOOD = {"n_trials": 900, "n_cases": 744, "n_untriggered": 156}


@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan"), 3.7, 1e300, -3, "70", None, True])
def test_a_value_that_is_no_count_reads_as_not_recorded(value):
    counts = TrainingCounts.from_meta(GOOD | {"n_cases": value})
    assert counts.windows is None and counts.trials == 900
    assert counts.text() == "900 labelled trials (how many windows they gave was not recorded)"


def test_a_whole_float_is_a_count():
    assert TrainingCounts.from_meta(GOOD | {"n_cases": 744.0}).windows == 744


def test_more_dormant_windows_than_windows_is_not_worded_as_a_negative_count():
    counts = TrainingCounts.from_meta(GOOD | {"n_cases": 10, "dormant_windows": 15})
    assert "-" not in counts.text() and counts.windows is None, counts.text()


def test_more_untriggered_trials_than_trials_is_not_worded():
    counts = TrainingCounts.from_meta(GOOD | {"n_trials": 5, "n_untriggered": 8})
    assert counts.trials is None and "gave no window" not in counts.text(), counts.text()
    assert counts.text() == "744 windows"


def test_the_counts_a_trainer_writes_read_back_as_written():
    counts = TrainingCounts(trials=48, windows=70, untriggered=2, dormant=22)
    assert TrainingCounts.from_meta(counts.to_meta()) == counts
    assert counts.text() == "70 windows: 48 from 48 labelled trials (2 gave no window) + 22 dormant windows from idle"


def test_the_prior_s_windows_are_said_beside_the_lab_s():
    counts = TrainingCounts(trials=108, windows=144, dormant=36, prior=432, prior_dormant=120)
    assert TrainingCounts.from_meta(counts.to_meta()) == counts
    assert counts.text() == ("144 windows: 108 from 108 labelled trials + 36 dormant windows from idle; plus 432 "
                             "simulated windows of the product's prior (120 dormant)")
    assert "prior_windows" not in TrainingCounts(trials=1, windows=1).to_meta()  # none without the prior
    odd = TrainingCounts.from_meta(counts.to_meta() | {"prior_dormant_windows": 500})
    assert odd.prior == 0 and "prior" not in odd.text()
