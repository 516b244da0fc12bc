"""What a model swap changes beyond the file: the trigger that cuts windows, the pads read, the classes.

A model carries the trigger it was trained with, and a swap serves the new one's unless the
config pins it; a model trained with the paper's threshold swapped in silently changes when
events are reported (the threshold fires on idle grasps far more often). So a swap that changes
the trigger's kind or settings, the pads or the classes is logged as a WARNING saying from what
to what, and the health view shows the trigger serving now (``trigger_text``).
"""

from __future__ import annotations

from typing import Any

__all__ = ["served", "swap_warning", "trigger_text"]

_SHOWN = {"onset": ("change", "floor", "back_frames", "refractory_s"),
          "threshold": ("fraction", "hysteresis", "refractory_s"),
          "baseline": ("fraction", "baseline_tau_s", "refractory_s")}
"""The settings named in a trigger's text, per kind (the rest are in the model card and the config)."""


def trigger_text(settings: Any) -> str | None:
    """``onset (change 0.12, floor 0.25, refractory_s 1.5)``: the trigger and its main settings."""
    if settings is None:
        return None
    name = settings.name
    shown = ", ".join(f"{k} {getattr(settings, k):g}" for k in _SHOWN.get(name, ()))
    return f"{name} ({shown})" if shown else name


def _pads(pads: Any) -> str:
    return "[" + ", ".join(str(p) for p in pads) + "]" if pads is not None else "none"


def swap_changes(old: dict[str, Any] | None, new: dict[str, Any]) -> list[str]:
    """``from -> to`` phrases for what differs between two served models' ``served(...)`` views."""
    if old is None:
        return []
    out = []
    if old["trigger"] != new["trigger"]:
        out.append(f"trigger {trigger_text(old['trigger'])} -> {trigger_text(new['trigger'])}")
    if tuple(old["pads"]) != tuple(new["pads"]):
        out.append(f"pads {_pads(old['pads'])} -> {_pads(new['pads'])}")
    if tuple(old["classes"]) != tuple(new["classes"]):
        out.append(f"classes {list(old['classes'])} -> {list(new['classes'])}")
    return out


def served(settings: Any, pads: Any, classes: Any) -> dict[str, Any]:
    """What a serving model means to the stream: its trigger settings, its pads, its classes."""
    return {"trigger": settings, "pads": tuple(pads), "classes": tuple(classes)}


def swap_warning(model_file: str, old: dict[str, Any] | None, new: dict[str, Any]) -> str | None:
    """The WARNING line for a swap that changes what is reported, or None when only the model changed."""
    changes = swap_changes(old, new)
    if not changes:
        return None
    return (f"model {model_file} changes what is reported: {'; '.join(changes)} (set [trigger] in the config to "
            "pin the trigger whatever the model was trained with)")
