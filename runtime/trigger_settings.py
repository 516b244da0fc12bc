"""Which trigger starts a window, with which settings: decided in one place.

``resolve_trigger(config, model_trigger)`` takes each setting from the ``[trigger]`` table, else from
the model's metadata, else from the default below; the daemon, the training data set and the stream
benchmark all call it, so training and serving cut the same windows. Kinds: ``onset`` (default,
runtime/onset.py; chosen in results/streams.md) and ``threshold`` (the paper's fixed level, optionally
over a tracked baseline). A model that records no ``kind`` was cut by the threshold and is served so.
"""

from __future__ import annotations

import math
from dataclasses import asdict, field, make_dataclass
from typing import Any

from firmware_io.trigger_level import PAPER_FRACTION  # noqa: F401 - the threshold's default level, named here
from runtime.config_keys import key, section_keys

__all__ = [
    "DEFAULT_HYSTERESIS", "DEFAULT_KIND", "HYSTERESIS_CAP", "TriggerSettings", "build_trigger",
    "capped_hysteresis", "recorded_problems", "resolve_trigger", "window_start_text"
]

_TRIGGER_KEYS = section_keys("trigger", config_only=False)
DEFAULT_KIND: str = key("trigger.kind").default
DEFAULT_HYSTERESIS: float = key("trigger.hysteresis").default
"""The threshold re-arms below (fraction - hysteresis) x full scale."""
HYSTERESIS_CAP = 0.99
"""A hysteresis is capped at 0.99 x the fraction, so the re-arm level stays above zero."""


def _to_meta(self: Any) -> dict[str, Any]:
    """The model metadata's ``trigger`` object (``fraction`` always present: the contract needs it)."""
    return asdict(self)


def _name(self: Any) -> str:
    """``onset``, ``threshold`` or ``baseline`` (the threshold above a tracked baseline)."""
    return "baseline" if self.kind == "threshold" and self.baseline else self.kind


TriggerSettings = make_dataclass(
    "TriggerSettings",
    [(k.short, k.type.__name__, field(default=k.default)) for k in _TRIGGER_KEYS],
    frozen=True,
    namespace={"__module__": __name__, "to_meta": _to_meta, "name": property(_name),
               "__doc__": "Everything that decides where a window starts (recorded in a model's metadata): "
                          "one field per ``trigger`` key of runtime/config_keys.py, its default the key's."},
)

_FROM_MODEL = tuple(k.short for k in _TRIGGER_KEYS if k.recorded)
"""Settings a model's metadata may carry (what its training windows were cut with)."""


def recorded_problems(recorded: dict) -> list[str]:
    """What is wrong with a model's recorded trigger settings (a hostile or broken file must
    be refused when loaded, not crash the daemon when it builds the trigger). ``fraction`` is the
    model contract's own check (runtime/model.py)."""
    problems = []
    kind = recorded.get("kind")
    if kind is not None and kind not in key("trigger.kind").choices:
        problems.append(f"trigger.kind {kind!r} must be one of {', '.join(key('trigger.kind').choices)}")
    for k in _TRIGGER_KEYS:
        value = recorded.get(k.short)
        if not k.recorded or k.range is None or k.short == "fraction" or value is None:
            continue
        lo, hi = k.range
        number = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        if not number or not lo <= value <= hi or (k.type is int and not isinstance(value, int)):
            kind = "a whole number" if k.type is int else "a number"
            problems.append(f"trigger.{k.short} {value!r} must be {kind} in [{lo:g}, {hi:g}]")
    return problems


def window_start_text(recorded: dict) -> str:
    """Where a model's windows start, in words, from its recorded ``trigger`` object (as it is served)."""
    s = resolve_trigger(None, recorded)
    back = s.back_frames if s.kind == "onset" else 0
    where = (f"where the departure began (at most {back} frames before the trigger fired)" if back
             else "the trigger frame")
    return f"window from {where}" + (f" and {s.pre_frames} frames before" if s.pre_frames else "")


def capped_hysteresis(fraction: float, hysteresis: float = DEFAULT_HYSTERESIS) -> float:
    """The hysteresis used with this fraction: at most ``HYSTERESIS_CAP`` x the fraction (a
    level of 0.02 with the default 0.05 would otherwise re-arm below zero, i.e. never)."""
    return min(float(hysteresis), float(fraction) * HYSTERESIS_CAP)


def resolve_trigger(config: Any = None, model_trigger: dict | None = None) -> TriggerSettings:
    """The trigger settings in force: config value, else the model's recorded one, else the default.

    ``config`` is a ``runtime.config.TriggerConfig`` (or None); ``model_trigger`` the model's
    metadata ``trigger`` object (or None when there is no model yet).
    """
    from runtime.config import TriggerConfig  # runtime.config builds its classes from the keys too

    cfg = config if config is not None else TriggerConfig()
    recorded = dict(model_trigger or {})
    if model_trigger is not None and "kind" not in recorded:
        recorded["kind"] = "threshold"  # cut before the onset trigger existed
    if model_trigger is not None and recorded.get("back_frames") is None:
        recorded["back_frames"] = 0  # cut at the trigger frame, before windows were dated back
    default = TriggerSettings(kind=str(cfg.kind or recorded.get("kind") or DEFAULT_KIND))
    chosen: dict[str, Any] = {}
    for name in _FROM_MODEL:
        value = getattr(cfg, name, None)
        if value is None and name in recorded and recorded[name] is not None:
            value = recorded[name]
        chosen[name] = getattr(default, name) if value is None else value
    values = {k.short: k.type(chosen[k.short] if k.recorded else getattr(cfg, k.short)) for k in _TRIGGER_KEYS}
    values["hysteresis"] = capped_hysteresis(values["fraction"], values["hysteresis"])
    return TriggerSettings(**values)


def build_trigger(s: TriggerSettings, pad_sizes: tuple[int, ...] | list[int], fullscale: float, window: int,
                  rate_hz: float, pad_fingers: tuple[int, ...] | list[int] | None = None) -> Any:
    """The trigger object for a scene (pads' column counts in row order) and a model's T.

    ``pad_fingers``: the finger of each pad (``SensorLayout.pad_fingers``; None: every pad its own)."""
    from runtime.onset import OnsetTrigger
    from runtime.trigger import ThresholdTrigger

    pre = min(int(s.pre_frames), window - 1)
    refractory = math.ceil(s.refractory_s * rate_hz)
    if s.kind == "onset":
        return OnsetTrigger(pad_sizes, fullscale, change=s.change, floor=s.floor, contact=s.contact,
                            tau_frames=max(1.0, s.track_tau_s * rate_hz), settle_frames=max(1, round(s.settle_s * rate_hz)),
                            settle_change=s.settle_change, refractory_frames=refractory, window=window, pre_frames=pre,
                            pad_fingers=pad_fingers, back_frames=min(int(s.back_frames), window - 1 - pre))
    return ThresholdTrigger(
        int(sum(pad_sizes)), fullscale, fraction=s.fraction, hysteresis=s.hysteresis, refractory_frames=refractory,
        window=window, pre_frames=pre, rearm_frames=max(1, math.ceil(s.rearm_quiet_s * rate_hz - 1e-9)),
        baseline=s.baseline, baseline_alpha=min(1.0, 1.0 / max(1.0, s.baseline_tau_s * rate_hz)),
    )
