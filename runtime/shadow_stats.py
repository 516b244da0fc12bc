"""What a candidate in shadow did since it arrived, against the serving model, and the one rule that judges it.

The rule (``verdict``; docs/GUIDE.md, "A candidate in shadow"): the candidate raises no more events where
the serving model saw nobody act than the serving model raises where the candidate saw nobody act; and,
once the robot's outcomes judge enough events (``judged_right``), it is right on no fewer of them; until
then nobody knows which of two models was right on a window, so it must mostly agree.
"""

from __future__ import annotations

import time

from runtime.health import Latency

__all__ = ["MIN_WINDOWS", "Comparison", "judged_right", "verdict"]

MIN_WINDOWS = 100
"""Windows compared before the rule judges (fewer say little about a day's handovers)."""
MIN_AGREEMENT = 0.9
"""The share of windows on which the candidate must decide the serving model's class (without outcomes)."""
MIN_OUTCOMES = 20
"""Events judged by the robot's outcomes before they, not agreement, decide."""


def judged_right(cls: str, word: str, classes: tuple[str, ...]) -> bool | None:
    """Whether deciding ``cls`` on an event was right by the robot's outcome ``word``, or None when the word
    cannot tell. The words are field capture's (firmware_io.recordings.field_capture): a class name is a
    person's label; ``taken``: the person took the object, a pull; ``kept``: the object stayed, anything but a
    pull; ``dropped``: it fell, whatever the person did."""
    if word in classes:
        return cls == word
    if word == "taken":
        return cls == "pull"
    if word == "kept":
        return cls != "pull"
    return None


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
        self.outcomes: dict[int, tuple[bool, bool]] = {}
        """An event's last frame -> (serving right, candidate right) by the robot's last word on it."""

    def judge(self, frame_last: int, serving_right: bool, candidate_right: bool) -> None:
        """The robot's outcome on the event ending at ``frame_last`` judged both models (a later word replaces it)."""
        self.outcomes[frame_last] = (serving_right, candidate_right)

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
        judged = list(dict(self.outcomes).values())
        return {"candidate_id": self.candidate_id, "candidate_file": self.candidate_file,
                "since": round(self.since, 3), "windows_compared": self.compared,
                "agreement": round(self.agreed / self.compared, 4) if self.compared else None,
                "confusion": confusion, "false_events_on_serving_dormant": self.candidate_extra,
                "serving_events_on_candidate_dormant": self.serving_extra,
                "latency_p50_us": lat["latency_p50_us"], "latency_p99_us": lat["latency_p99_us"],
                "windows_dropped": dropped - self.dropped_before, "events_with_outcome": len(judged),
                "serving_right": sum(s for s, _ in judged), "candidate_right": sum(c for _, c in judged),
                "verdict": verdict(self)}


def verdict(c: Comparison) -> str:
    """One line: whether the candidate passes the shadow rule (module docstring), and on what figures."""
    name = f"candidate {c.candidate_id} ({c.candidate_file})"
    judged = list(dict(c.outcomes).values())
    extra = (f"{c.candidate_extra} events where serving saw none against {c.serving_extra} the other way "
             "(rule: no more)")
    if len(judged) >= MIN_OUTCOMES:
        right, serving = sum(x for _, x in judged), sum(s for s, _ in judged)
        figures = (f"right on {right} of {len(judged)} events the robot's outcome judges, the serving model on "
                   f"{serving} (rule: no fewer), {extra}")
        passed = right >= serving
    elif c.compared >= MIN_WINDOWS:
        agreement = c.agreed / c.compared
        figures = (f"agrees on {agreement:.1%} of {c.compared} windows (rule without {MIN_OUTCOMES} events judged by "
                   f"the robot's outcome: >= {MIN_AGREEMENT:.0%}), {extra}")
        passed = agreement >= MIN_AGREEMENT
    else:
        return (f"{name}: not judged yet, {c.compared} of {MIN_WINDOWS} windows compared, {len(judged)} of "
                f"{MIN_OUTCOMES} events judged by the robot's outcome")
    if passed and c.candidate_extra <= c.serving_extra:
        return f"{name} passes the shadow rule: {figures}; promote it by moving its file (docs/GUIDE.md)"
    return f"{name} fails the shadow rule: {figures}"
