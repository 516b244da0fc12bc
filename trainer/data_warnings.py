"""What a lab's recordings can carry, said once: how thin the dormant class is, which subjects are partial,
and whether the recordings come from more than one simulated lab.

Why: a dormant class cut from a few windows of one idle kind, or a subject who recorded 12 of 180
trials, gives report rows that look as good as those of enough data. ``handover train`` prints each
line here on the console (seen even with --quiet) and report.md repeats it; the report marks a partial
subject's rows instead of showing its 100 %.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from firmware_io.recordings.idle_stretches import RECORD_IDLE_COMMAND, SOURCES, has_idle

__all__ = ["FEW_DORMANT_WINDOWS", "data_notes", "dormant_lines", "idle_kinds_text", "lab_line", "partial_subjects",
           "prior_lab_line"]

FEW_DORMANT_WINDOWS = 100
"""Fewer dormant windows than this and the class is called thin. The rule of three: with n windows and
every one read right, the data cannot exclude (95 %) that 3 in n idle windows are read as an action;
at 100 that is 3 %. The recorder's default (3 min of idle a subject) gives 12-16 windows a subject."""
MORE_IDLE = f"`{RECORD_IDLE_COMMAND}` (every idle kind, in rounds of 81 s)"
"""The command that records more idle of every kind, as the lines say it."""


@dataclass
class DataNotes:
    """The lines about the data (console and report) and the partial subjects (subject -> what it lacks)."""

    lines: list[str] = field(default_factory=list)
    partial: dict[str, str] = field(default_factory=dict)


def _kind(origin: str) -> str:
    """The idle kind of a dormant window's origin (``trigger:arm_move`` -> ``arm_move``)."""
    return origin.rsplit(":", 1)[-1]


def _by_kind(per_origin: dict[str, int]) -> dict[str, int]:
    kinds: dict[str, int] = {}
    for origin, n in per_origin.items():
        kinds[_kind(origin)] = kinds.get(_kind(origin), 0) + int(n)
    return kinds


def idle_kinds_text(per_origin: dict[str, int]) -> str:
    """Windows per idle kind, e.g. ``arm_move 54, quiet 1``: an origin's cut and prefix are not a reader's words."""
    return ", ".join(f"{k} {n}" for k, n in sorted(_by_kind(per_origin).items()))


def dormant_lines(per_origin: dict[str, int], recorded: Sequence[str], prior: dict[str, int] | None = None
                  ) -> list[str]:
    """Lines when the lab's dormant windows are few or of one idle kind (``per_origin``: the lab's windows per
    origin; ``recorded``: the idle kinds the recordings hold; ``prior``: the simulator's dormant windows the
    model is fit on too, by origin). Counted on the lab's windows: the prior's come from the simulator's hand,
    not the lab's, and are never scored; the lines name both, so they say what the class rests on."""
    kinds = _by_kind(per_origin)
    total = sum(kinds.values())
    sim = _by_kind(prior or {})
    rests = f"the dormant class rests on {total} windows of your idle" + (
        f" and {sum(sim.values())} of the simulator's (the product's prior: {idle_kinds_text(sim)}; another hand "
        "than yours)" if sim else "")
    lines = []
    if total < FEW_DORMANT_WINDOWS:
        lines.append(f"{rests}: fewer than {FEW_DORMANT_WINDOWS} of your own; even with every one read right, your "
                     f"data cannot exclude that {min(1.0, 3 / max(total, 1)):.0%} of your idle windows are read as an "
                     f"action (95 %, rule of three); record more idle: {MORE_IDLE}")
    if len(kinds) == 1:
        (only,) = kinds
        missing = [k for k in SOURCES if k != only]
        quiet = [k for k in missing if k in recorded]
        absent = [k for k in missing if k not in recorded]
        why = []
        if quiet:
            why.append(f"{', '.join(quiet)} recorded but the trigger fired on none of them (a model served in "
                       "continuous mode meets them untrained on your hand)")
        if absent:
            why.append(f"{', '.join(absent)} not recorded ({MORE_IDLE} records them)")
        lines.append(f"{rests}: your idle gave one idle kind only (its {total} windows are all {only}); "
                     + "; ".join(why))
    return lines


def recorded_kinds(recordings: Sequence) -> list[str]:
    """The idle kinds (``SOURCES``) any recording holds frames of."""
    seen: set[str] = set()
    for rec in recordings:
        if has_idle(rec.meta):
            names = rec.meta["sources"]
            codes = np.unique(np.asarray(rec.meta["source_codes"], dtype=np.int64))
            seen |= {str(names[c]) for c in codes if 0 <= c < len(names)}
    return [k for k in SOURCES if k in seen]


def planned_trials(meta: dict) -> int | None:
    """The trials the recording's last recording session planned (``handover record``'s protocol), or None."""
    sessions = meta.get("sessions") if isinstance(meta, dict) else None
    plans = [s["protocol"] for s in sessions if isinstance(s, dict) and isinstance(s.get("protocol"), dict)] \
        if isinstance(sessions, list) else []
    if not plans:
        return None
    p = plans[-1]
    try:
        return len(p["poses"]) * len(p["objects"]) * len(p["actions"]) * int(p["runs"])
    except (KeyError, TypeError, ValueError):
        return None


def partial_subjects(recordings: Sequence, names: Sequence[str]) -> dict[str, str]:
    """Subject -> what its recordings lack: fewer trials than planned, or no idle while others have idle.
    A daemon's captured events and idle (``meta[META_KEY]``) follow no protocol: never partial."""
    from firmware_io.recordings.field_capture import META_KEY
    from trainer.recorded_idle import idle_pieces, subject_of

    trials: dict[str, int] = {}
    planned: dict[str, int] = {}
    idle: dict[str, bool] = {}
    for rec, name in zip(recordings, names, strict=True):
        if META_KEY in rec.meta:
            continue
        subject = subject_of(rec, Path(name).stem)
        idle[subject] = idle.get(subject, False) or bool(idle_pieces(rec))
        if rec.trials:
            trials[subject] = trials.get(subject, 0) + len(rec.trials)
            if (n := planned_trials(rec.meta)) is not None:
                planned[subject] = planned.get(subject, 0) + n
    others_idle = any(idle[s] for s in trials)
    out = {}
    for subject, n in sorted(trials.items()):
        lacks = []
        if subject in planned and n < planned[subject]:
            lacks.append(f"{n} of {planned[subject]} planned trials")
        if others_idle and not idle[subject]:
            lacks.append("no idle")
        if lacks:
            out[subject] = ", ".join(lacks)
    return out


def lab_line(recordings: Sequence, names: Sequence[str]) -> str | None:
    """One line when the synthetic recordings come from more than one simulated lab (``firmware_io.sim.lab``):
    said, not refused (a lab may mean to mix them), naming each lab's files."""
    from firmware_io.sim.lab import lab_of

    files: dict[str, list[str]] = {}
    for rec, name in zip(recordings, names, strict=True):
        if (lab := lab_of(rec.meta)) is not None:
            files.setdefault(lab, []).append(Path(name).name)
    if len(files) < 2:
        return None
    said = "; ".join(f"lab {lab}: {', '.join(f[:3])}" + (f" and {len(f) - 3} more" if len(f) > 3 else "")
                     for lab, f in sorted(files.items()))
    return (f"the recordings come from {len(files)} simulated labs ({said}): one model learns both hands and both "
            "sets of people; train on one lab's files for a model of that lab")


def prior_lab_line(recordings: Sequence, prior_lab: str) -> str | None:
    """One line when synthetic recordings come from a simulated lab other than the prior's (``trainer.prior``)."""
    from firmware_io.sim.lab import lab_of

    labs = [lab_of(rec.meta) for rec in recordings]
    others = sorted({lab for lab in labs if lab not in (None, prior_lab)})
    if not others:
        return None
    simulated = [lab for lab in labs if lab is not None]
    n = sum(lab in others for lab in simulated)  # mixed with the prior's own lab: say how many
    who = "the recordings come" if n == len(simulated) else f"{n} of {len(simulated)} simulated recordings come"
    return (f"{who} from simulated lab {', '.join(others)} and the product's prior is simulated lab "
            f"{prior_lab} (another hand and other people): its weight is chosen on your subjects alone (0 when it "
            "does not help them); --no-prior trains on your recordings alone")


def data_notes(recordings: Sequence, names: Sequence[str], idle, prior_lab: str | None = None,
               prior_dormant: dict[str, int] | None = None) -> DataNotes:
    """Everything above for one training run (``idle``: ``trainer.recorded_idle.IdleWindows`` or None;
    ``prior_lab``: the simulated lab of the prior training adds, None without one; ``prior_dormant``: the
    simulated dormant windows the model is fit on besides the lab's, by origin)."""
    notes = DataNotes(partial=partial_subjects(recordings, names))
    if line := lab_line(recordings, names):
        notes.lines.append(line)
    if prior_lab and (line := prior_lab_line(recordings, prior_lab)):
        notes.lines.append(line)
    if idle is not None and idle.makes_class:
        notes.lines += dormant_lines(idle.per_source, recorded_kinds(recordings), prior_dormant)
    for subject, lacks in notes.partial.items():
        notes.lines.append(f"{subject} is a partial recording ({lacks}): its rows in the report say partial, not "
                           f"their accuracy; the same `handover record --device URL --subject {subject} "
                           "--out DIR` command (with its session's options) records what it lacks")
    return notes
