"""Idle stretches of a recorded session: the hand's time with nobody interacting, labelled by what went on.

A model that never saw the hand held while the arm moves, regrasps, closes or opens reads some of that
as a person's action, so each session records such stretches under the simulator's idle source names
(recorded and simulated idle data are cut and scored by the same code). ``meta["idle_stretches"]``
keeps them; ``meta["sources"]``/``meta["source_codes"]`` are derived from them on every save. numpy only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

SOURCES = ("open", "quiet", "grasp", "release", "arm_move", "regrasp")
"""What an idle frame shows (index = code in ``meta["source_codes"]``): open hand; grasp held,
nothing happening; the hand closing on an object; the hand opening; the arm moving; the hand
re-seating its grasp."""

PROMPTS = {
    "grasp": "Place the object in the hand and close the hand on it; nobody touches it afterwards.",
    "quiet": "Hold the object still; nobody touches it.",
    "arm_move": "Move the arm now (the robot's usual moves, nobody touches the object).",
    "regrasp": "Re-grasp: loosen the hand a little and close it again on the object.",
    "release": "Open the hand and let the object go.",
    "open": "Hand open and empty; nobody touches it.",
}
"""What the recorder says at the start of each kind of stretch."""

CYCLE = (("grasp", 5.0), ("quiet", 20.0), ("arm_move", 15.0), ("regrasp", 10.0), ("arm_move", 15.0),
         ("release", 5.0), ("open", 6.0))
"""One round of idle stretches (source, seconds): every kind in the order a robot meets them, arm
moves twice (a service arm moves most of the time it holds something). A plan repeats the round
until it has the minutes asked for, so any length keeps the mix."""

DEFAULT_IDLE_MINUTES = 3.0
"""Idle recorded per subject after the trials (``handover record --idle-minutes``)."""
MAX_IDLE_MINUTES = 24 * 60.0
"""The longest idle session one command plans: a day (the plan is listed before recording starts, so an
endless one would never start)."""


@dataclass(frozen=True, order=True)
class IdleSlot:
    """One stretch of the plan: its place, what goes on, how long."""

    index: int
    source: str
    seconds: float

    def describe(self) -> str:
        return f"idle stretch {self.index + 1}: {self.source.replace('_', ' ')}, {self.seconds:g} s"

    @property
    def prompt(self) -> str:
        return PROMPTS[self.source]


def idle_plan(minutes: float, cycle: Sequence[tuple[str, float]] = CYCLE) -> list[IdleSlot]:
    """Stretches of the round ``cycle`` repeated until ``minutes`` are reached (none for 0); ValueError
    for minutes outside 0..MAX_IDLE_MINUTES (NaN planned nothing without a word, infinity never returned)."""
    if not 0 <= minutes <= MAX_IDLE_MINUTES:
        raise ValueError(f"idle minutes must be from 0 to {MAX_IDLE_MINUTES:g} (a day), got {minutes:g}")
    out: list[IdleSlot] = []
    total = 0.0
    while total < 60.0 * minutes - 1e-9:
        source, seconds = cycle[len(out) % len(cycle)]
        out.append(IdleSlot(len(out), source, float(seconds)))
        total += seconds
    return out


def stretch_codes(n_frames: int, stretches: Sequence[dict]) -> np.ndarray:
    """Per frame the index into SOURCES of its stretch, ``-1`` outside every stretch (trials)."""
    code = np.full(n_frames, -1, dtype=np.int8)
    for s in stretches:
        code[int(s["first"]):int(s["last"]) + 1] = SOURCES.index(str(s["source"]))
    return code


def stretches_of(meta: dict) -> list[dict]:
    """The idle stretches a recording's metadata lists (recorded, or imported as idle)."""
    raw = meta.get("idle_stretches") if isinstance(meta, dict) else None
    if not isinstance(raw, list):
        return []
    return [s for s in raw if isinstance(s, dict) and s.get("source") in SOURCES
            and isinstance(s.get("first"), int) and isinstance(s.get("last"), int)]


def has_idle(meta: dict) -> bool:
    """Whether a recording holds idle frames coded by source (recorded, imported or simulated)."""
    codes, names = meta.get("source_codes"), meta.get("sources")
    return isinstance(codes, list) and isinstance(names, list) and any(c >= 0 for c in codes)


def codes_problem(meta: dict, n_frames: int) -> str | None:
    """Why ``meta["sources"]`` / ``meta["source_codes"]`` cannot code ``n_frames`` frames, or None
    (also when both are absent). Checked when a recording is read, so a damaged file is refused
    in one line naming it instead of failing deep inside training or replay."""
    codes, names = meta.get("source_codes"), meta.get("sources")
    if codes is None and names is None:
        return None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        return "meta.sources must be a list of idle source names"
    if (not isinstance(codes, list) or len(codes) != n_frames
            or not all(isinstance(c, int) and not isinstance(c, bool) and -1 <= c < len(names) for c in codes)):
        return (f"meta.source_codes must hold one code per frame ({n_frames}), each from -1 (a trial) "
                f"to {len(names) - 1}")
    return None


def idle_meta(n_frames: int, stretches: Sequence[dict]) -> dict:
    """The metadata keys a recording with these stretches carries (empty without stretches)."""
    if not stretches:
        return {}
    return {"idle_stretches": [dict(s) for s in stretches], "sources": list(SOURCES),
            "source_codes": stretch_codes(n_frames, stretches).tolist()}


RECORD_IDLE_COMMAND = "handover record --device URL --idle-only --idle-minutes 20 --subject ID --out DIR"
"""The command that records more idle of every kind, as every hint writes it (it runs when copied)."""

__all__ = [
    "CYCLE", "DEFAULT_IDLE_MINUTES", "RECORD_IDLE_COMMAND", "SOURCES", "IdleSlot", "codes_problem", "has_idle", "idle_meta", "idle_plan",
    "stretches_of"
]
