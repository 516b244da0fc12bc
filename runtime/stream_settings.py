"""Which stream settings a model serves, from what its file records (the one place that says so).

A stream setting is how the daemon turns frames into events (results/streams.md): ``onset`` (the
onset trigger starts a window, a four-class model names it), ``onset_dormant`` (the same, and a
window the model reads as dormant is not reported), ``continuous`` (every frame classified, needs
a dormant class) and ``threshold`` (the paper's fixed level). A model records the trigger that
cut its training windows and whether it has a dormant class; both decide what it serves. The
first setting is the one the daemon runs it in by default (``[scene] mode = "trigger"``).
"""

from __future__ import annotations

__all__ = ["SETTINGS", "describe", "served_settings"]

SETTINGS = {
    "onset": "onset trigger; every window it starts is reported",
    "onset_dormant": "onset trigger; a window read as dormant is not reported",
    "threshold": "the paper's threshold trigger",
    "threshold_dormant": "the paper's threshold trigger; a window read as dormant is not reported",
    "continuous": "every frame classified ([scene] mode = \"continuous\"), one report per interaction",
}


def served_settings(dormant_class: str | None, trigger: dict | None) -> list[str]:
    """The settings a model with this dormant class and recorded trigger serves, its default first."""
    kind = trigger.get("kind", "threshold") if isinstance(trigger, dict) else "threshold"
    first = "onset" if kind == "onset" else "threshold"
    if dormant_class:
        return [f"{first}_dormant", "continuous"]
    return [first]


def describe(dormant_class: str | None, trigger: dict | None, dormant_cut: str | None = None) -> str:
    """One line for a model card: the settings and what each does (``dormant_cut``: how the training
    cut its dormant windows, ``trigger`` = only where the trigger fired on idle, so continuous mode,
    which asks about every window, is accepted but not what it was trained for)."""
    names = served_settings(dormant_class, trigger)
    text = "; ".join(f"{n} ({SETTINGS[n]})" for n in names)
    if dormant_class and dormant_cut == "trigger":
        text += ("; continuous is accepted, but its dormant windows are only those the trigger cut on idle, "
                 "so it was not trained for every window")
    if not dormant_class:
        text += "; not continuous (no dormant class)"
    return text
