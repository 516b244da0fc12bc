"""How much a model was trained on: labelled trials, the windows cut from them, dormant windows from idle.

A trial is what a person did once; a window (a case) is T frames the model learnt from. A trial that
never triggers gives no window, idle gives dormant windows that are no trial, and stream training cuts
several windows per trial, so the two numbers differ and must never be printed under each other's
name. The trainer counts them once (``trainer.dataset.Dataset.counts``); the model carries them in its
``training`` metadata under the keys below; train's progress line, its headline, report.md and
``handover inspect`` all word them with ``TrainingCounts.text``. Lives in the runtime because
``inspect`` must read it on the lean daemon install.
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

    def to_meta(self) -> dict:
        """The model metadata's ``training`` keys (``dormant_windows`` only when the model has them)."""
        meta = {"n_trials": self.trials, "n_cases": self.windows, "n_untriggered": self.untriggered}
        return meta | ({"dormant_windows": self.dormant} if self.dormant else {})

    @classmethod
    def from_meta(cls, training: Mapping) -> TrainingCounts:
        """Read back ``to_meta``'s keys; a value that is no count reads as not recorded."""

        def count(key: str) -> int | None:
            v = training.get(key)
            return int(v) if isinstance(v, int | float) and not isinstance(v, bool) and v == v and v >= 0 else None

        return cls(trials=count("n_trials"), windows=count("n_cases"), untriggered=count("n_untriggered") or 0,
                   dormant=count("dormant_windows") or 0)

    def text(self) -> str:
        """``70 windows: 48 from 48 labelled trials + 22 dormant windows from idle`` and its shorter forms."""
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
