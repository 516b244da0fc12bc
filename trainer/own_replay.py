"""Stream figures from a lab's own recordings: each held-out subject replayed through the daemon.

Why: what a robot meets is events right, wrong or missed, and false events, not window accuracy. For
every subject (and idle-only recording) a model trained without it is exported and that recording is
replayed through the daemon's code (``trainer.streams_eval.replay``): each trial from its held grasp,
each idle stretch on its own. A trial's event is right when its first report (from ``EARLY_FRAMES``
before the reference) names its action; reports in idle are false events per hour. The reference is
the annotated onset where there is one, else the go cue.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from firmware_io.frame_timing import NOMINAL_PERIOD_S
from firmware_io.recordings import arm_marks
from firmware_io.recordings.idle_stretches import RECORD_IDLE_COMMAND
from firmware_io.recordings.recording import Recording
from runtime.event_rate import rate_text
from trainer import streams_eval as se
from trainer.rate_interval import rate_interval
from trainer.recorded_idle import idle_pieces, subject_of

__all__ = ["SHORT_IDLE_MIN", "held_out_replay", "real_false_meta", "replay_lines"]

SHORT_IDLE_MIN = 30.0
"""Below this much recorded idle the report says what one false event weighs per hour: there a single
event moves the rate by more than the gap between a usable model and a nuisance."""


def stream_mode(dormant: bool, trigger_kind: str) -> str:
    """The stream setting (``streams_eval.MODES``) a trigger-mode model is replayed in."""
    if trigger_kind == "onset":
        return "onset_dormant" if dormant else "onset"
    return "threshold"


def model_stream_mode(model) -> str:
    """``stream_mode`` of a loaded model (its dormant class and the trigger kind it is served with)."""
    from runtime.trigger_settings import resolve_trigger

    return stream_mode(bool(model.meta.dormant_class), resolve_trigger(None, model.meta.trigger).kind)


def _segment(rec: Recording, first: int, last: int, meta: dict | None = None) -> Recording:
    sl = slice(first, last + 1)
    return Recording(rec.layout, rec.frames[sl], rec.timestamps[sl], [], dict(meta or {}))


def _reference(trial) -> tuple[int, str]:
    """(frame within the trial the event counts from, what it is)."""
    onset = trial.extra.get("onset") if isinstance(trial.extra, dict) else None
    if isinstance(onset, int):
        if 0 <= onset < trial.n_frames:
            return onset, "onset"
        if trial.first <= onset <= trial.last:
            return onset - trial.first, "onset"
    go = trial.extra.get("go_frame") if isinstance(trial.extra, dict) else None
    if isinstance(go, int) and 0 <= go < trial.n_frames:
        return go, "go"
    return 0, "start"


def replay_recording(rec: Recording, model, mode: str) -> dict:
    """Trials and idle pieces of one recording replayed through the daemon (``model``: a loaded model)."""
    period = rec.period_s()
    events, delays, refs = [], [], set()
    early = 0
    for tr in rec.trials:
        ref, kind = _reference(tr)
        refs.add(kind)
        decisions = se.replay(_segment(rec, tr.first, tr.last), model, mode)
        owned = [d for d in decisions if d.frame >= ref - se.EARLY_FRAMES]
        early += len(decisions) - len(owned)
        first = owned[0] if owned else None
        outcome = "missed" if first is None else "right" if first.cls == tr.action else "wrong"
        events.append({"action": tr.action, "outcome": outcome, "reported": first.cls if first else None})
        if first is not None:
            delays.append(first.frame - ref)
    idle_frames: dict[str, int] = {}
    false_by: dict[str, int] = {}
    false_classes: dict[str, int] = {}
    with_arm: dict[str, int] = {}
    arm_mode = f"{mode}_arm" if f"{mode}_arm" in se.ARM_MODES else None
    for first, last, _ in idle_pieces(rec):
        piece = _segment(rec, first, last, {"sources": rec.meta["sources"],
                                            "source_codes": rec.meta["source_codes"][first:last + 1],
                                            arm_marks.KEY: arm_marks.piece_marks(rec.meta, rec.n_frames, first, last)})
        names = se.source_names(piece, piece.n_frames)
        for name, n in zip(*np.unique(names.astype(str), return_counts=True), strict=True):
            idle_frames[str(name)] = idle_frames.get(str(name), 0) + int(n)
        for d in se.replay(piece, model, mode):
            name = str(names[d.frame]) if 0 <= d.frame < piece.n_frames else "?"
            false_by[name] = false_by.get(name, 0) + 1
            false_classes[d.cls] = false_classes.get(d.cls, 0) + 1
        if arm_mode:  # the robot's words stored while recording, else 'arm moving' over the arm_move stretches
            for d in se.replay(piece, model, arm_mode):
                name = str(names[d.frame]) if 0 <= d.frame < piece.n_frames else "?"
                with_arm[name] = with_arm.get(name, 0) + 1
    return {"events": events, "delays": delays, "early": early, "references": sorted(refs), "period": period,
            "idle_frames": idle_frames, "false_by_source": false_by, "false_by_class": false_classes,
            "false_by_source_arm_messages": with_arm if arm_mode else None}


def summarize(parts: Sequence[dict]) -> dict:
    """Pooled figures over replayed recordings."""
    events = [e for p in parts for e in p["events"]]
    count = {k: sum(e["outcome"] == k for e in events) for k in ("right", "wrong", "missed")}
    period = float(np.median([p["period"] for p in parts])) if parts else NOMINAL_PERIOD_S
    frames = se.sum_counts(p["idle_frames"] for p in parts)
    false = se.sum_counts(p["false_by_source"] for p in parts)
    hours = {k: v * period / 3600.0 for k, v in frames.items()}
    total_h = sum(hours.values())
    n_false = sum(false.values())
    delays = np.array([d for p in parts for d in p["delays"]], dtype=np.float64)
    per_action: dict[str, dict] = {}
    for e in events:
        a = per_action.setdefault(e["action"], {"n": 0, "right": 0})
        a["n"] += 1
        a["right"] += e["outcome"] == "right"
    classes = se.sum_counts(p["false_by_class"] for p in parts)
    arm = None
    if parts and all(p.get("false_by_source_arm_messages") is not None for p in parts):
        arm = se.sum_counts(p["false_by_source_arm_messages"] for p in parts)
    arm_h = hours.get("arm_move", 0.0)
    return {
        "events": len(events), **count, "early_reports": sum(p["early"] for p in parts),
        "right_fraction": count["right"] / len(events) if events else None,
        "per_action": dict(sorted(per_action.items())),
        "idle_hours": total_h, "false_events": n_false, "false_per_hour": n_false / total_h if total_h else None,
        "false_per_hour_95": rate_interval(n_false, total_h),
        "idle_by_source": {k: {"hours": hours[k], "false_events": false.get(k, 0),
                               "false_per_hour": false.get(k, 0) / hours[k] if hours[k] else None}
                           for k in sorted(hours)},
        "false_by_class": dict(sorted(classes.items())),
        "with_arm_messages": None if arm is None else {
            "false_events": sum(arm.values()), "false_per_hour": sum(arm.values()) / total_h if total_h else None,
            "arm_move_false_events": arm.get("arm_move", 0),
            "arm_move_false_per_hour": arm.get("arm_move", 0) / arm_h if arm_h else None},
        "onset_to_report_frames": se._stats(delays), "period": period,
        "reference": sorted({r for p in parts for r in p["references"]}),
    }


def held_out_replay(ds, estimator, recordings: Sequence[Recording], names: Sequence[str],
                    say: Callable[[str], None], heads_of: dict | None = None) -> dict | None:
    """Every subject (or idle-only recording) held out in turn: a model trained without it, exported,
    its recording replayed through the daemon. None when there is nothing to hold out against.
    ``heads_of``: per held-out group, early heads and rule chosen without it (``trainer.early.fold_heads``),
    exported with that fold's model so its early reports are scored too."""
    from sklearn.base import clone

    from runtime.model import load_model
    from trainer.dormant import DORMANT
    from trainer.model_meta import dataset_metadata
    from trainer.onnx_export import export_onnx
    from trainer.pipeline import looks_simulated

    dormant = DORMANT in ds.classes
    mode = stream_mode(dormant, ds.trigger.kind)
    owners = [subject_of(r, Path(n).stem) for r, n in zip(recordings, names, strict=True)]
    groups = sorted({g for g, r in zip(owners, recordings, strict=True) if r.trials or idle_pieces(r)})
    if len(groups) < 2:
        return None
    folds, parts, skipped, cont = [], [], {}, []
    with tempfile.TemporaryDirectory(prefix="handover-replay-") as tmp:
        for k, group in enumerate(groups):
            train = ds.groups != group
            classes = set(ds.y[train].tolist())
            if len(classes - {DORMANT}) < 2:
                skipped[group] = "the other recordings hold fewer than two actions"
                continue
            say(f"  replaying {group} through the daemon ({mode}), model trained without it "
                f"({k + 1}/{len(groups)}) ...")
            model = clone(estimator).fit(ds.X[train], ds.y[train])
            meta = dataset_metadata(ds, training={"held_out": group}, dormant_class=DORMANT if dormant else None)
            heads = (heads_of or {}).get(group)
            path = export_onnx(model, Path(tmp) / f"fold{k}.onnx", meta, early=heads)
            loaded = load_model(path, warm_up=False)
            mine = [{**replay_recording(r, loaded, mode), "synthetic": looks_simulated(r.meta)}
                    for r, g in zip(recordings, owners, strict=True) if g == group]
            if dormant:  # the real idle in continuous mode too: every setting the model serves gets its figure
                cont += [idle_reports(r, loaded, "continuous") for r, g in zip(recordings, owners, strict=True)
                         if g == group and not looks_simulated(r.meta)]
            fold = summarize(mine)
            folds.append({"held_out": group, "early_heads": heads is not None, **{key: fold[key] for key in (
                "events", "right", "wrong", "missed", "idle_hours", "false_events", "false_per_hour")}})
            parts += mine
    if not parts:
        return {"mode": mode, "skipped": skipped, "folds": []}
    early = sum(f["early_heads"] for f in folds)
    return {"mode": mode, "dormant_class": dormant, **summarize(parts), "folds": folds, "skipped": skipped,
            "real_idle": _real_part(parts, mode, cont),
            "early_heads": f"{early} of {len(folds)} folds" if early else "none (the full window only)"}


def idle_reports(rec: Recording, model, mode: str) -> tuple[float, int]:
    """(hours, reports) of a recording's idle pieces replayed through the daemon in ``mode``."""
    hours, reports = 0.0, 0
    for first, last, _ in idle_pieces(rec):
        hours += (last - first + 1) * rec.period_s() / 3600.0
        reports += len(se.replay(_segment(rec, first, last), model, mode))
    return hours, reports


def _real_part(parts: Sequence[dict], mode: str, continuous: Sequence[tuple[float, int]] = ()) -> dict | None:
    """The idle of the recordings that are not synthetic (a real hand's signals), pooled, per stream setting
    (``mode``, and ``continuous`` when replayed: (hours, reports) per recording); None without any."""
    real = [p for p in parts if not p["synthetic"]]
    r = summarize(real) if real else None
    if not r or not r["idle_hours"]:
        return None
    out = {"mode": mode, "recordings": len(real), "hours": r["idle_hours"], "events": r["false_events"],
           "per_hour": r["false_per_hour"]}
    settings = {mode: {k: out[k] for k in ("hours", "events", "per_hour")}}
    hours, events = sum(h for h, _ in continuous), sum(n for _, n in continuous)
    if hours:
        settings["continuous"] = {"hours": hours, "events": events, "per_hour": events / hours}
    return {**out, "settings": settings}


def real_false_meta(replay: dict | None) -> dict:
    """The model file's ``runtime.model_meta.REAL_FALSE_KEY`` entry from the held-out replay's real idle
    ({} when none was replayed: the model then carries no figure, which reads as unmeasured)."""
    from runtime.model_meta import REAL_FALSE_KEY

    r = (replay or {}).get("real_idle")
    if not r:
        return {}
    data = (f"handover train's held-out replay of {r['recordings']} real recording(s)' idle, each through a model "
            "trained without its subject")
    settings = r.get("settings") or {r["mode"]: r}
    return {REAL_FALSE_KEY: {name: {"per_hour": v["per_hour"], "events": v["events"], "hours": v["hours"], "data": data}
                             for name, v in settings.items()}}


def replay_lines(r: dict | None) -> list[str]:
    """The held-out replay in a few lines (terminal and report)."""
    if not r or not r.get("folds"):
        return []
    ref = {"onset": "the annotated onset", "go": "the go cue", "start": "the trial's start"}
    refs = " / ".join(ref.get(x, x) for x in r["reference"]) or "-"
    lines = []
    if r["events"]:
        d = r["onset_to_report_frames"]
        ms = 1000.0 * r.get("period", NOMINAL_PERIOD_S)
        lines.append(f"events: {r['events']} trials, {r['right']} right ({r['right_fraction']:.0%}), {r['wrong']} wrong, "
                     f"{r['missed']} missed, {r['early_reports']} reports before the action; onset to report: "
                     + (f"median {d['median']:.0f} frames ({d['median'] * ms:.0f} ms), p90 {d['p90']:.0f} frames "
                        f"({d['p90'] * ms:.0f} ms) from {refs}; early heads: {r.get('early_heads', 'none')}" if d else "-"))
    if r["idle_hours"]:
        by = ", ".join(f"{k} {v['false_events']} in {v['hours'] * 60:.1f} min"
                       for k, v in r["idle_by_source"].items())
        ci = r.get("false_per_hour_95") or rate_interval(r["false_events"], r["idle_hours"])
        lines.append(f"idle: false events {rate_text(r['false_events'], r['idle_hours'])}, 95 % interval "
                     f"{ci[0]:.1f}-{ci[1]:.1f}/h ({r['idle_hours'] * 60:.1f} min: {by})")
        minutes = r["idle_hours"] * 60
        if minutes < SHORT_IDLE_MIN:
            lines.append(f"{minutes:.1f} min of idle: one false event is {1 / r['idle_hours']:.1f} per hour; record more "
                         f"idle (`{RECORD_IDLE_COMMAND}`) for a tighter figure")
        arm = r.get("with_arm_messages")
        if arm:
            lines.append(f"idle with the robot's 'arm moving' / 'arm still' over the arm_move stretches: "
                         f"false events {rate_text(arm['false_events'], r['idle_hours'])}; during arm moves "
                         f"{arm['arm_move_false_events']}")
    else:
        lines.append("idle: none recorded, so false events per hour are not measured (handover record records idle "
                     "after the trials)")
    real = r.get("real_idle")
    if not real and not r["idle_hours"]:
        return lines
    lines.append(f"real idle signals ({real['recordings']} recordings not synthetic): "
                 + ", ".join(f"false events {rate_text(v['events'], v['hours'], 2)} in {k}"
                             for k, v in (real.get("settings") or {real["mode"]: real}).items())
                 + ", written into the model (handover inspect)" if real else
                 "real idle signals: none (every idle recording is synthetic), so the model's real false events per "
                 "hour are unmeasured (handover inspect says so)")
    return lines


def real_idle(model, root: Path, say, files: Sequence[Path] | None = None, mode: str | None = None) -> dict | None:
    """False events of the model on every real SDH-2 recording (none holds a handover), or on ``files`` of them,
    in ``mode`` (default: the setting the model serves by default)."""
    from firmware_io.recordings.importers import import_any
    from trainer.shared_data import real_files

    if not root.is_dir():
        return None
    mode = mode or ("onset_dormant" if model.meta.dormant_class else "onset")
    rows, hours, events = [], 0.0, 0
    for path, cat, _ in real_files(root):
        if files is not None and path not in files:
            continue
        try:
            rec = import_any(path)
            found = se.replay(rec, model, mode)
        except Exception as exc:  # a file the importers or the scene refuse is listed, not counted
            rows.append({"file": str(path.relative_to(root)), "skipped": str(exc)[:200]})
            continue
        h = float(rec.timestamps[-1] - rec.timestamps[0]) / 3600.0 if rec.n_frames > 1 else 0.0
        hours += h
        events += len(found)
        rows.append({"file": str(path.relative_to(root)), "category": cat, "hours": h,
                     "events": [d.cls for d in found]})
    say(f"{len(rows)} real recordings replayed ({hours:.2f} h): {events} events, none is a handover")
    return {"root": str(root), "mode": mode, "hours": hours, "events": events,
            "false_per_hour": events / hours if hours else None, "rows": rows}


def real_idle_line(r: dict) -> str:
    """The real recordings without a handover in one line."""
    return (f"  real SDH-2 recordings without a handover ({r['root']}): false events "
            f"{rate_text(r['events'], r['hours'], 2)} ({r['mode']})")
