"""What a candidate in shadow did since it arrived, against the serving model, and the one rule that judges it.

Why a rule of its own: without the robot's outcomes nobody knows which of two models was right on a
window, so the rule (``verdict``; docs/GUIDE.md, "A candidate in shadow") asks only what can be
seen: that the candidate mostly agrees, and that it raises no more events where the serving model
saw nobody act than the serving model raises where the candidate saw nobody act.
"""

from __future__ import annotations

import time

from runtime.health import Latency

__all__ = ["MIN_WINDOWS", "Comparison", "verdict"]

MIN_WINDOWS = 100
"""Windows compared before the rule judges (fewer say little about a day's handovers)."""
MIN_AGREEMENT = 0.9
"""The share of windows on which the candidate must decide the serving model's class."""


class Comparison:
    """The candidate against the serving model on the same windows. Written by the shadow thread only;
    the health view reads it (``figures``) from the daemon's loop."""

    def __init__(self, candidate_id: str, candidate_file: str, dropped_before: int) -> None:
        self.candidate_id, self.candidate_file = candidate_id, candidate_file
        self.since = time.time()
        self.dropped_before = dropped_before
        """The shadow's dropped windows when the candidate arrived (the figures count from then)."""
        self.compared = 0
        self.agreed = 0
        self.confusion: dict[tuple[str, str], int] = {}
        """(serving class, candidate class) -> windows."""
        self.candidate_extra = 0
        """Windows the candidate reported as an event while the serving model said dormant or reported none."""
        self.serving_extra = 0
        """Windows the serving model reported as an event while the candidate would have reported none."""
        self.latency = Latency()

    def add(self, serving: str, serving_reported: bool, candidate: str, reported: bool, latency_us: float) -> None:
        """One window: both models' classes, whether each would be reported, the candidate's decision time."""
        self.compared += 1
        self.agreed += serving == candidate
        key = (serving, candidate)
        self.confusion[key] = self.confusion.get(key, 0) + 1
        self.candidate_extra += reported and not serving_reported
        self.serving_extra += serving_reported and not reported
        self.latency.record(latency_us)

    def figures(self, dropped: int) -> dict:
        """The health view's ``shadow`` figures; ``dropped``: the shadow's dropped windows in all."""
        confusion: dict[str, dict[str, int]] = {}
        for (serving, candidate), n in sorted(dict(self.confusion).items()):  # a copy: the shadow thread adds
            confusion.setdefault(serving, {})[candidate] = n
        lat = self.latency.counters()
        return {"candidate_id": self.candidate_id, "candidate_file": self.candidate_file,
                "since": round(self.since, 3), "windows_compared": self.compared,
                "agreement": round(self.agreed / self.compared, 4) if self.compared else None,
                "confusion": confusion, "false_events_on_serving_dormant": self.candidate_extra,
                "serving_events_on_candidate_dormant": self.serving_extra,
                "latency_p50_us": lat["latency_p50_us"], "latency_p99_us": lat["latency_p99_us"],
                "windows_dropped": dropped - self.dropped_before, "verdict": verdict(self)}


def verdict(c: Comparison) -> str:
    """One line: whether the candidate passes the shadow rule (module docstring), and on what figures."""
    name = f"candidate {c.candidate_id} ({c.candidate_file})"
    if c.compared < MIN_WINDOWS:
        return f"{name}: not judged yet, {c.compared} of {MIN_WINDOWS} windows compared"
    agreement = c.agreed / c.compared
    figures = (f"agrees on {agreement:.1%} of {c.compared} windows (rule: >= {MIN_AGREEMENT:.0%}), "
               f"{c.candidate_extra} events where serving saw none against {c.serving_extra} the other way "
               "(rule: no more)")
    if agreement >= MIN_AGREEMENT and c.candidate_extra <= c.serving_extra:
        return f"{name} passes the shadow rule: {figures}; promote it by moving its file (docs/GUIDE.md)"
    return f"{name} fails the shadow rule: {figures}"
