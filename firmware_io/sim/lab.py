"""Simulated labs: the hand and the people a recording comes from, one fixed row each.

Lab ``A`` is the simulator as calibrated on the Kiechle recordings (its values are the constants'
and its bytes for a seed are those of the simulator before labs existed). Lab ``B`` is another
hand and other people, shifted from ``A`` at least as far as the two real SDH-2 sources differ
(docs/SIMULATOR.md, "A second lab": the measurement and the rule). Rows are fixed; they are never
tuned toward a detector's score. Every part of the chain reads its lab from here.
"""

from __future__ import annotations

from dataclasses import dataclass

from firmware_io.errors import HandoverError
from firmware_io.sim import constants as K
from firmware_io.sim.scenario import OBJECT_MODELS, OBJECTS

__all__ = ["DEFAULT_LAB", "LABS", "Lab", "UnknownLab", "get_lab", "lab_of"]


class UnknownLab(HandoverError, ValueError):
    """A lab name no row has."""


@dataclass(frozen=True)
class Lab:
    """What differs between two labs: the hand's pads and grip, the people, the objects."""

    name: str
    summary: str
    pad_gain: tuple[float, ...]  # sensitivity of each pad (layout order), times the per-taxel spread
    idle_mean: float  # counts an untouched taxel reads before the threshold (the noise floor's level)
    noise_sd: float  # temporal noise of an untouched taxel (counts)
    dead_taxels: int  # taxels that read 0 for good (broken traces), drawn once per hand
    hot_taxels: int  # taxels whose idle reading sits at the threshold: they flicker non-zero untouched
    grip: float  # the hand controller's grasp force, times the default's
    strength: float  # the people's force, times the default's
    speed: float  # the people's movement speed, times the default's
    objects: tuple[str, ...]  # what stands in for the protocol's ball, cylinder, plank (same order)

    @property
    def key(self) -> tuple[str, ...]:
        """Added to the random streams of this lab's hand and people (none for A: its bytes stay)."""
        return () if self.name == DEFAULT_LAB else ("lab", self.name)

    @property
    def meta(self) -> dict:
        """What a recording's meta says about its lab: nothing for A (its files stay as they were)."""
        return {"lab": self.name} if self.key else {}

    def object_for(self, name: str) -> str:
        """The object this lab hands over for a protocol's object name (its own names pass through)."""
        if name in self.objects:
            return name
        return self.objects[OBJECTS.index(name)] if name in OBJECTS else self.objects[0]


DEFAULT_LAB = "A"

LABS = {
    "A": Lab("A", "the default simulator, calibrated on Kiechle's hand", (1.0,) * 6, K.IDLE_READING_MEAN,
             K.IDLE_NOISE_SD, 0, 0, 1.0, 1.0, 1.0, OBJECTS),
    "B": Lab("B", "another hand and other people: more sensitive pads, a noisier floor, dead taxels, firmer grip, "
                  "stronger and slower people, a bottle and a sponge",
             (3.5, 3.15, 3.85, 2.8, 3.5, 3.15), 52.0, 2.6, 12, 2, 1.3, 1.25, 0.8, ("ball", "bottle", "sponge")),
}
"""Lab B's row, chosen once (docs/SIMULATOR.md gives each value's reason and the measurement)."""

assert all(o in OBJECT_MODELS for lab in LABS.values() for o in lab.objects)


def get_lab(name: str | Lab | None = None) -> Lab:
    """The lab of this name (None: the default); an unknown one raises UnknownLab naming the labs."""
    if isinstance(name, Lab):
        return name
    key = DEFAULT_LAB if name is None or str(name).strip() == "" else str(name).strip().upper()
    if key not in LABS:
        raise UnknownLab(f"unknown lab {str(name)[:20]!r}; the labs are "
                         + ", ".join(f"{n} ({lab.summary.split(':')[0].split(',')[0]})" for n, lab in LABS.items()))
    return LABS[key]


def lab_of(meta: dict) -> str | None:
    """The simulated lab a recording's meta names: A for a synthetic one that names none (written before
    labs, or by lab A), None for a real recording."""
    if not meta.get("synthetic"):
        return None
    return str(meta.get("lab") or DEFAULT_LAB)
