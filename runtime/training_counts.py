"""How much a model was trained on: labelled trials, the windows cut from them, dormant windows from idle,
and the windows the product's prior (simulated, trainer/prior.py) added to the lab's.

Trials and windows differ (a trial may give no window or several; idle gives windows that are no
trial), so they must never be printed under each other's name: every place words them with
``TrainingCounts.text``. In the runtime because ``inspect`` reads it on the lean daemon install.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["TrainingCounts"]


@dataclass(frozen=True)
class TrainingCounts:
    """The counts of one training set; None: not recorded (a bare estimator, an old model)."""

    trials: int | None
    """Labelled trials seen, those that gave a window and those that gave none."""
    windows: int | None
    """Windows the model was trained on, dormant ones included."""
    untriggered: int = 0
    """Labelled trials that gave no window (listed with their reasons by the trainer)."""
    dormant: int = 0
    """Windows of the dormant class, cut from idle (no trial's)."""
    prior: int = 0
    """Simulated windows the product's prior added to these (none counted in ``windows``)."""
    prior_dormant: int = 0
    """Of ``prior``, the dormant ones."""

    def to_meta(self) -> dict:
        """The model metadata's ``training`` keys (``dormant_windows``, ``prior_*`` only when the model has them)."""
        meta = {"n_trials": self.trials, "n_cases": self.windows, "n_untriggered": self.untriggered}
        return (meta | ({"dormant_windows": self.dormant} if self.dormant else {})
                | ({"prior_windows": self.prior, "prior_dormant_windows": self.prior_dormant} if self.prior else {}))

    @classmethod
    def from_meta(cls, training: Mapping) -> TrainingCounts:
        """Read back ``to_meta``'s keys; a value that is no count (3.7, inf, 1e300, "70"), and counts that
        contradict each other (more dormant windows than windows), read as not recorded: the card
        words them, and must not print a negative number nor crash on hand-edited metadata."""

        def count(key: str) -> int | None:
            v = training.get(key)
            # a float is a count only when whole and exact (not NaN, inf, or 1e300's 301 digits)
            whole = isinstance(v, int) or (isinstance(v, float) and v.is_integer() and abs(v) <= 2.0**53)
            return int(v) if whole and not isinstance(v, bool) and v >= 0 else None

        trials, windows = count("n_trials"), count("n_cases")
        untriggered, dormant = count("n_untriggered") or 0, count("dormant_windows") or 0
        if windows is not None and dormant > windows:
            windows, dormant = None, 0
        if trials is not None and untriggered > trials:
            trials, untriggered = None, 0
        prior, prior_dormant = count("prior_windows") or 0, count("prior_dormant_windows") or 0
        if prior_dormant > prior:
            prior, prior_dormant = 0, 0
        return cls(trials=trials, windows=windows, untriggered=untriggered, dormant=dormant, prior=prior,
                   prior_dormant=prior_dormant)

    def text(self) -> str:
        """``70 windows: 48 from 48 labelled trials + 22 dormant windows from idle`` and its shorter forms, then
        ``; plus 210 simulated windows of the product's prior (90 dormant)`` when the prior joined."""
        prior = (f"; plus {self.prior} simulated windows of the product's prior ({self.prior_dormant} dormant)"
                 if self.prior else "")
        return self._own() + prior

    def _own(self) -> str:
        if self.windows is None:
            return ("an unknown number of windows (not recorded)" if self.trials is None
                    else f"{self.trials} labelled trials (how many windows they gave was not recorded)")
        from_trials = self.windows - self.dormant
        source = "action windows" if self.trials is None else f"from {self.trials} labelled trials"
        if self.untriggered:
            source += f" ({self.untriggered} gave no window)"
        if not self.dormant:
            return f"{self.windows} windows {source}" if self.trials is not None else f"{self.windows} windows"
        return f"{self.windows} windows: {from_trials} {source} + {self.dormant} dormant windows from idle"
