"""Which stream settings a model serves, from what its file records (the one place that says so).

A stream setting is how the daemon turns frames into events (results/streams.md): ``onset`` (the
onset trigger starts a window, a four-class model names it), ``onset_dormant`` (the same, and a
window the model reads as dormant is not reported), ``continuous`` (every frame classified, needs
a dormant class) and ``threshold`` (the paper's fixed level). A model records the trigger that
cut its training windows and whether it has a dormant class; both decide what it serves. The
first setting is the one the daemon runs it in by default (``[scene] mode = "trigger"``).
"""

from __future__ import annotations

from firmware_io.recordings.idle_stretches import RECORD_IDLE_COMMAND
from runtime.event_rate import rate_text

__all__ = ["SETTINGS", "cost_lines", "describe", "served_setting", "served_settings"]

SETTINGS = {
    "onset": "onset trigger; every window it starts is reported",
    "onset_dormant": "onset trigger; a window read as dormant is not reported",
    "threshold": "the paper's threshold trigger",
    "threshold_dormant": "the paper's threshold trigger; a window read as dormant is not reported",
    "continuous": "every frame classified ([scene] mode = \"continuous\"), one report per interaction",
}


MAX_REAL_FALSE_PER_HOUR = 1.0
"""A setting raising more false events per hour than this on real idle signals is said to cost too much
(the product's bar: the default onset_dormant stays below it on the real recordings, results/streams.json)."""
RECORD_IDLE = f"record idle on the robot (`{RECORD_IDLE_COMMAND}`) and train again (`handover train` measures it on that idle)"


def served_setting(dormant_class: str | None, trigger_kind: str, scene_mode: str = "trigger") -> str:
    """The setting the daemon serves a model in: ``[scene] mode`` and the trigger kind in force
    (``runtime.trigger_settings.resolve_trigger``: the config's, else the model's)."""
    if scene_mode == "continuous":
        return "continuous"
    first = "onset" if trigger_kind == "onset" else "threshold"
    return f"{first}_dormant" if dormant_class else first


def cost_lines(meta, settings: list[str] | None = None) -> list[str]:
    """One line per setting (default: every one the model serves) whose false events per hour on real idle
    signals are unmeasured, above ``MAX_REAL_FALSE_PER_HOUR``, or measured on too few hours to show it is
    below (fewer than one event at the bar), with what to do; none for one below."""
    from runtime.model_meta import real_false_events

    measured = real_false_events(meta)
    enough = 1.0 / MAX_REAL_FALSE_PER_HOUR  # hours in which one false event is the bar itself
    fine = {k: v for k, v in measured.items() if v["per_hour"] <= MAX_REAL_FALSE_PER_HOUR and v["hours"] >= enough}
    lines = []
    for name in settings or served_settings(meta.dormant_class, meta.trigger):
        others = [f"serve {k} ({rate_text(v['events'], v['hours'], 2)})" for k, v in fine.items() if k != name]
        if name == "continuous" and not others:  # the trigger asks the model far less often (results/streams.json)
            others = ['serve it with the trigger ([scene] mode = "trigger"): on the real recordings continuous mode '
                      "raised far more false events than onset_dormant (results/streams.md)"]
        if name not in measured:
            why = ("trained on synthetic data" if meta.training.get("synthetic") else
                   "trained without idle" if not meta.training.get("idle_seconds") else "its idle did not measure it")
            lines.append(f"stream setting {name}: false events on real idle signals unmeasured for this model ({why}); "
                         + "; or ".join([RECORD_IDLE, *others]))
        elif (m := measured[name])["per_hour"] > MAX_REAL_FALSE_PER_HOUR:
            lines.append(f"stream setting {name}: false events {rate_text(m['events'], m['hours'], 2)} on real idle "
                         f"signals ({m['data']}), above {MAX_REAL_FALSE_PER_HOUR:g} per hour; "
                         + "; or ".join([*others, RECORD_IDLE.replace("record idle", "record more idle")]))
        elif m["hours"] < enough:
            lines.append(f"stream setting {name}: {m['events']} false events in only {m['hours']:.2f} h of real idle "
                         f"({m['data']}): one event there is {1 / m['hours']:.1f} per hour, so it cannot show the "
                         f"setting stays below {MAX_REAL_FALSE_PER_HOUR:g} per hour; "
                         + "; or ".join([*others, RECORD_IDLE.replace("record idle", f"record at least {enough:g} h "
                                                                      "of idle")]))
    return lines


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
