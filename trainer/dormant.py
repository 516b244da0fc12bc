"""A fifth class, "dormant": windows in which nobody interacts, so the runtime can classify every frame.

A continuously classifying model sees every T-frame window, so its training windows are cut the way
the stream presents them: *action* windows at several positions around the annotated onset; *dormant*
windows from the protocol's frames before the onset, from the simulated hand's idle streams
(stratified by the rarest thing in view) and from handover sessions' placing and taking away. Models
are the unchanged classifiers and exporter; the metadata names ``dormant_class`` so the daemon accepts
the model for ``scene.mode = "continuous"``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from firmware_io.recordings.recording import Recording
from runtime.training_counts import TrainingCounts
from trainer.dataset import fingerprint
from trainer.defaults import PAPER_MODEL, paper_classifier

__all__ = [
    "ACTION_LATE_MAX", "ACTION_VIEW_MIN", "DORMANT", "IDLE_FOLDS", "RAMP_WINDOWS", "TRANSITION_VISIBLE",
    "DormantDataset", "action_starts", "build_dormant_dataset", "export", "fit_stream_model", "idle_windows", "in_view",
    "leave_one_subject_out", "ramp_starts", "session_windows", "train", "trigger_windows"
]

DORMANT = "dormant"
ACTION_VIEW_MIN = 7
"""An action window shows at least this many frames from the onset (about half of T = 15)."""
ACTION_LATE_MAX = 4
"""... and starts at most this many frames after the onset."""
RAMP_WINDOWS: dict[str, tuple[int, int]] = {"hold": (2, 10)}
"""Per action, (n, last): n more windows per trial starting ACTION_LATE_MAX + 1 .. last frames after
the onset. A hold's grip ramps for 0.5-0.9 s; without them a continuously classifying model meets
the ramp's windows unlabelled and reads them as dormant. Chosen on validation streams
(benchmarks/studies/ramp_windows.py, results/ramp_windows.md)."""
WINDOWS_PER_TRIAL = 3
IDLE_WINDOWS_PER_SOURCE = 250
IDLE_FOLDS = 5
"""Idle-stream windows get a group per contiguous fifth of each stream (for leave-one-out folds)."""
TRANSITION_VISIBLE = 3
"""A place / take-away window ends at least this many frames into the hand's 0.3 s close /
open ramp (smoothstep: about a quarter of the way), so the transition is in view."""
TRANSITION_PRIORITY = ("release", "grasp", "regrasp", "arm_move")
"""The idle sources a window is attributed to when any of its frames shows them (rarest first)."""


@dataclass
class DormantDataset:
    """Cases ``X`` float32 ``(n, C, T)``, labels (four actions + dormant) and where each came from."""

    X: np.ndarray
    y: np.ndarray
    groups: np.ndarray
    """Subject for protocol and session windows, ``idle0`` .. ``idle4`` for idle-stream windows."""
    origin: np.ndarray
    """``action``, ``pre_onset`` or ``idle:<source>``."""
    pads: tuple[int, ...]
    pad_sizes: tuple[int, ...]
    T: int
    fullscale: float
    fingerprint: str

    def counts(self, trials: int | None = None) -> TrainingCounts:
        """Windows as every report states them; ``trials``: the labelled trials they were cut from
        (several windows each), which this set does not keep."""
        return TrainingCounts(trials=trials, windows=len(self.y), dormant=int(np.sum(self.y == DORMANT)))

    def summary(self) -> dict:
        kinds, counts = np.unique(self.origin, return_counts=True)
        classes, per_class = np.unique(self.y, return_counts=True)
        return {"n_cases": len(self.y), "per_class": dict(zip(classes.tolist(), per_class.tolist(), strict=True)),
                "per_origin": dict(zip(kinds.tolist(), counts.tolist(), strict=True)), "T": self.T,
                "pads": list(self.pads), "fingerprint": self.fingerprint}


def _onset(trial) -> int | None:
    onset = trial.extra.get("onset") if isinstance(trial.extra, dict) else None
    if onset is None:
        return None
    onset = int(onset)
    if 0 <= onset < trial.n_frames:  # the protocol's convention: within the trial
        return onset
    if trial.first <= onset <= trial.last:  # a session's absolute frame
        return onset - trial.first
    return None


def action_starts(onset: int, n_frames: int, T: int) -> np.ndarray:
    """Window starts that show >= ACTION_VIEW_MIN frames of the action and start <= ACTION_LATE_MAX after it."""
    lo = max(0, onset - T + ACTION_VIEW_MIN)
    hi = min(n_frames - T, onset + ACTION_LATE_MAX)
    return np.arange(lo, hi + 1) if hi >= lo else np.zeros(0, dtype=np.int64)


def ramp_starts(action: str, onset: int, n_frames: int, T: int, rng: np.random.Generator) -> list[int]:
    """RAMP_WINDOWS' later window starts for one trial of ``action`` (none for an action without them)."""
    n, last = RAMP_WINDOWS.get(action, (0, 0))
    lo, hi = onset + ACTION_LATE_MAX + 1, min(n_frames - T, onset + last)
    if not n or hi < lo:
        return []
    return [int(s) for s in rng.choice(np.arange(lo, hi + 1), size=min(n, hi - lo + 1), replace=False)]


def protocol_windows(recordings: Sequence[Recording], cols: np.ndarray, T: int, rng: np.random.Generator,
                     per_trial: int = WINDOWS_PER_TRIAL) -> tuple[list, list, list, list]:
    """Action windows around each onset and one dormant window ending just before it."""
    X, y, groups, origin = [], [], [], []
    for rec in recordings:
        for trial in rec.trials:
            onset = _onset(trial)
            if onset is None:
                continue
            frames = rec.frames[trial.first:trial.last + 1, cols]
            starts = action_starts(onset, len(frames), T)
            picked = list(rng.choice(starts, size=min(per_trial, len(starts)), replace=False)) if len(starts) else []
            picked += ramp_starts(trial.action, onset, len(frames), T, rng)
            for s in picked:
                X.append(frames[s:s + T].T)
                y.append(trial.action)
                groups.append(trial.subject)
                origin.append("action")
            if onset - 1 >= T:  # the last window entirely before the person acts
                X.append(frames[onset - 1 - T:onset - 1].T)
                y.append(DORMANT)
                groups.append(trial.subject)
                origin.append("pre_onset")
    return X, y, groups, origin


def in_view(code: np.ndarray, names: Sequence[str], T: int) -> list[str | None]:
    """Per window end frame: the rarest transition any frame of the window shows, else the end frame's source."""
    out: list[str | None] = [None] * len(code)
    for k in range(T - 1, len(code)):
        out[k] = names[code[k]] if code[k] >= 0 else None
    for name in reversed(TRANSITION_PRIORITY):  # later (rarer) names overwrite
        if name not in names:
            continue
        hit = (code == names.index(name)).astype(np.int64)
        seen = np.convolve(hit, np.ones(T, dtype=np.int64))[:len(code)]  # frames of `name` in [k-T+1, k]
        for k in np.flatnonzero(seen[T - 1:] > 0) + T - 1:
            out[k] = name
    return out


def idle_windows(idle: Sequence[Recording], cols: np.ndarray, T: int, rng: np.random.Generator,
                 per_source: int = IDLE_WINDOWS_PER_SOURCE, group_of: Sequence[str] | None = None
                 ) -> tuple[list, list, list]:
    """Dormant windows from idle streams, up to ``per_source`` per kind of idle situation in view.

    A window counts for a transition (release, grasp, regrasp, arm move) when any of its
    frames shows it, otherwise for the source of its last frame. Returns windows, origins and
    groups (``idle0`` .. ``idle4``: the contiguous fifth of its stream, for held-out folds; or
    ``group_of[r]``, the group of the r-th stream, e.g. a recorded subject's).
    """
    ends: dict[str, list[tuple[int, int]]] = {}
    for r, rec in enumerate(idle):
        code = np.asarray(rec.meta["source_codes"])
        for k, name in enumerate(in_view(code, rec.meta["sources"], T)):
            if name is not None:
                ends.setdefault(name, []).append((r, k))
    X, origin, groups = [], [], []
    for source in sorted(ends):
        pool = ends[source]
        for i in rng.choice(len(pool), size=min(per_source, len(pool)), replace=False):
            r, k = pool[i]
            X.append(idle[r].frames[k - T + 1:k + 1, cols].T)
            origin.append(f"idle:{source}")
            groups.append(group_of[r] if group_of is not None else f"idle{IDLE_FOLDS * k // idle[r].n_frames}")
    return X, origin, groups


def trigger_windows(idle: Sequence[Recording], cols: np.ndarray, T: int, settings, pad_sizes: Sequence[int],
                    fullscale: float, pad_fingers: Sequence[int] | None = None,
                    group_of: Sequence[str] | None = None) -> tuple[list, list, list]:
    """Dormant windows where the daemon's trigger fires on idle streams: what a trigger-mode model
    with a dormant class is asked about while nobody interacts (the window its ``update`` says ends,
    as the daemon and ``trainer.dataset`` cut). Each stream is fed from its first
    frame to a fresh trigger that finds the settled grasp itself (no robot messages). Returns
    windows, origins (``trigger:<source of the firing frame>``) and groups (``group_of[r]`` or ``idle``).
    """
    from runtime.trigger_settings import build_trigger

    X, origin, groups = [], [], []
    for r, rec in enumerate(idle):
        rate = 1.0 / rec.period_s()
        trig = build_trigger(settings, tuple(pad_sizes), fullscale, T, rate, pad_fingers)
        frames = rec.frames[:, cols].astype(np.float32)
        code = rec.meta.get("source_codes")
        names = rec.meta.get("sources", ())
        for i in range(len(frames)):
            due = trig.update(frames[i], i)
            start = due - T + 1  # the window the daemon cuts (pre_frames and back_frames before the trigger frame)
            if due < 0 or start < 0 or start + T > len(frames):
                continue
            X.append(frames[start:start + T].T)
            source = names[code[i]] if code is not None and 0 <= code[i] < len(names) else "idle"
            origin.append(f"trigger:{source}")
            groups.append(group_of[r] if group_of is not None else "idle")
    return X, origin, groups


def session_windows(sessions: Sequence[Recording], cols: np.ndarray, T: int, rng: np.random.Generator,
                    per_kind: int = IDLE_WINDOWS_PER_SOURCE) -> tuple[list, list, list]:
    """Dormant windows of scripted sessions: the hand closing before the action, opening after it.

    ``place``: windows that end between ``TRANSITION_VISIBLE`` frames into the close and the
    last pre-onset frame; ``take_away``: windows that end from ``TRANSITION_VISIBLE`` frames
    into the opening (``RELEASE_AFTER_S`` after the onset) until the 0.3 s opening has left the
    window. Grouped by subject.
    """
    from firmware_io.sim import constants as K
    from firmware_io.sim.session import RELEASE_AFTER_S

    ramp = int(np.ceil(0.3 / K.FRAME_PERIOD_S))
    pools: dict[str, list[tuple[int, int, str]]] = {"place": [], "take_away": []}
    for r, rec in enumerate(sessions):
        level = rec.frames[:, cols].max(axis=1)
        for tr in rec.trials:
            onset = int(tr.extra["onset"])
            loaded = np.flatnonzero(level[tr.first:onset] > 0)
            if len(loaded):
                close = tr.first + int(loaded[0])
                for k in range(max(close + TRANSITION_VISIBLE, T - 1), onset - 1):
                    pools["place"].append((r, k, tr.subject))
            release = round(float(tr.extra.get("onset_s", onset * K.FRAME_PERIOD_S)) / K.FRAME_PERIOD_S
                                + RELEASE_AFTER_S / K.FRAME_PERIOD_S)
            for k in range(release + TRANSITION_VISIBLE, min(rec.n_frames, release + ramp + T - 1)):
                pools["take_away"].append((r, k, tr.subject))
    X, origin, groups = [], [], []
    for kind, pool in pools.items():
        for i in rng.choice(len(pool), size=min(per_kind, len(pool)), replace=False) if pool else ():
            r, k, subject = pool[i]
            X.append(sessions[r].frames[k - T + 1:k + 1, cols].T)
            origin.append(f"session:{kind}")
            groups.append(subject)
    return X, origin, groups


def build_dormant_dataset(protocol: Sequence[Recording], idle: Sequence[Recording], T: int = 15,
                          pads: str | Sequence[int] = "all", seed: int = 0,
                          per_source: int = IDLE_WINDOWS_PER_SOURCE,
                          sessions: Sequence[Recording] = ()) -> DormantDataset:
    """Five classes (the four actions + dormant) from the protocol, idle streams and sessions."""
    if not protocol:
        raise ValueError("no protocol recordings")
    layout = protocol[0].layout
    pad_idx = layout.pads(pads)
    cols = layout.columns(pad_idx)
    rng = np.random.default_rng(seed)
    X, y, groups, origin = protocol_windows(protocol, cols, T, rng)
    Xi, oi, gi = idle_windows(idle, cols, T, rng, per_source)
    Xs, os_, gs = session_windows(sessions, cols, T, rng, per_source)
    X += Xi + Xs
    y += [DORMANT] * (len(Xi) + len(Xs))
    groups += gi + gs
    origin += oi + os_
    if not X:
        raise ValueError("no windows: trials lack onsets and no idle stream was given")
    return DormantDataset(
        X=np.asarray(X, dtype=np.float32).reshape(len(X), len(cols), T),
        y=np.asarray(y).astype(str), groups=np.asarray(groups).astype(str), origin=np.asarray(origin).astype(str),
        pads=tuple(pad_idx), pad_sizes=tuple(layout.pad_sizes(pad_idx)), T=int(T),
        fullscale=float(max(layout.matrices[p].fullscale for p in pad_idx)),
        fingerprint=fingerprint(list(protocol) + list(idle) + list(sessions)),
    )


def leave_one_subject_out(ds: DormantDataset, K: int = PAPER_MODEL["K"], W: int = PAPER_MODEL["W"],
                          kernel: str = PAPER_MODEL["kernel"], seed: int = 0,
                          log=None) -> dict:
    """Window-level leave-one-subject-out of the 5-class model: per-class recall, dormant included.

    Fold i holds out subject i's protocol and session windows and the i-th fifth of the idle
    streams (``idle<i>``); the model (C, gamma by its own inner cross-validation) is trained
    on the rest. Same simulated hand in every fold (synthetic).
    """
    subjects = sorted({g for g in ds.groups.tolist() if not g.startswith("idle")})
    idle_groups = sorted({g for g in ds.groups.tolist() if g.startswith("idle")})
    classes = sorted(set(ds.y.tolist()))
    confusion = np.zeros((len(classes), len(classes)), dtype=np.int64)
    folds, per_origin = [], {}
    for i, subject in enumerate(subjects):
        test = ds.groups == subject
        if idle_groups:
            test |= ds.groups == idle_groups[i % len(idle_groups)]
        if log:
            log(f"  fold {i + 1}/{len(subjects)}: held out {subject} ({int(test.sum())} windows)")
        model = train(ds.X[~test], ds.y[~test], K, W, kernel, seed)
        pred = np.asarray(model.predict(ds.X[test])).astype(str)
        truth = ds.y[test]
        for t, q in zip(truth, pred, strict=True):
            confusion[classes.index(t), classes.index(q)] += 1
        for o, t, q in zip(ds.origin[test], truth, pred, strict=True):
            row = per_origin.setdefault(str(o), [0, 0])
            row[0] += int(t == q)
            row[1] += 1
        folds.append({"held_out": subject, "n": int(test.sum()), "accuracy": float(np.mean(truth == pred)),
                      "recall": {c: _ratio(np.sum((truth == c) & (pred == c)), np.sum(truth == c)) for c in classes}})
    acc = np.array([f["accuracy"] for f in folds])
    return {
        "classes": classes, "confusion": confusion.tolist(),
        "recall": {c: _ratio(confusion[k, k], confusion[k].sum()) for k, c in enumerate(classes)},
        "accuracy_mean": float(acc.mean()) if len(acc) else None, "accuracy_std": float(acc.std()) if len(acc) else None,
        "recall_by_origin": {o: _ratio(a, n) for o, (a, n) in sorted(per_origin.items())},
        "n_by_origin": {o: n for o, (_, n) in sorted(per_origin.items())},
        "folds": folds,
    }


def _ratio(a, n) -> float | None:
    return float(a) / float(n) if n else None


def train(X: np.ndarray, y: np.ndarray, K: int = PAPER_MODEL["K"], W: int = PAPER_MODEL["W"],
          kernel: str = PAPER_MODEL["kernel"], seed: int = 0):
    """The paper's estimator, unchanged (any number of classes)."""
    return paper_classifier(random_state=seed, n_words=K, window=W, kernel=kernel).fit(X, y)


STREAM_KERNEL, STREAM_C = "rbf", 1000.0
"""The stream model's SVM: RBF with C = 1000, what ``./dev bench dormant``'s grid chose for the 5-class
model (results/dormant.md); gamma by the usual inner cross-validation. With standardised level
features the grid's large C (1e4, 1e6) did not converge within many minutes."""


def fit_stream_model(protocol: Sequence[Recording], seed: int, idle_min: float, n_sessions: int,
                     path: str | Path, K: int = PAPER_MODEL["K"], W: int = PAPER_MODEL["W"], T: int = 15,
                     pads: str = "all", early: bool = True, log=None) -> Path:
    """The 5-class model for live streams (synthetic training data, ``seed``), exported to ``path``.

    Per-pad histograms plus per-pad level and slope (a hold is a change of level the derivative
    barely shows), standardised; ``idle_min`` minutes of idle stream and a session of
    ``n_sessions`` handovers for the dormant windows. The metadata records the onset trigger, so
    the daemon in trigger mode starts its windows at the person's onset and reports nothing for a
    window it reads as dormant; in continuous mode it classifies every frame.
    """
    from firmware_io.sim import demo_script, simulate_session
    from firmware_io.sim.idle import simulate_idle
    from runtime.trigger_settings import resolve_trigger

    n_parts = max(1, round(idle_min / 10))
    idle = [simulate_idle(60.0 * idle_min / n_parts, seed=seed, part=p) for p in range(n_parts)]
    sessions = [simulate_session(demo_script(n_sessions, seed=seed, gap=(4.0, 6.0)), seed=seed)]
    dds = build_dormant_dataset(protocol, idle, T=T, pads=pads, seed=seed, sessions=sessions)

    model = paper_classifier(dds.pad_sizes, seed, n_words=K, window=W, kernel=STREAM_KERNEL, C=STREAM_C, per_pad=True,
                             level_features=True, scale_features=True, fullscale=dds.fullscale).fit(dds.X, dds.y)
    heads = None
    if early:
        from trainer.early import fit_stream_heads

        heads = fit_stream_heads(protocol, dds, pads, seed, log=log)
    trigger = resolve_trigger().to_meta()
    return export(model, path, pads=dds.pads, pad_sizes=dds.pad_sizes, fullscale=dds.fullscale,
                  fraction=trigger["fraction"], trigger=trigger, sample_rate_hz=1.0 / protocol[0].sample_interval(),
                  dormant_class=DORMANT, training={
                      "data_fingerprint": dds.fingerprint,
                      **dds.counts(trials=sum(len(r.trials) for r in protocol)).to_meta(),
                      "synthetic": True, "seed": seed, "windows": dds.summary(), "level_features": True,
                      "data": f"protocol + {idle_min:g} min simulate_idle(seed={seed}) + "
                              f"simulate_session(demo_script({n_sessions}, seed={seed}))"}, early=heads)


def export(model, path: str | Path, *, pads: Sequence[int], pad_sizes: Sequence[int], fullscale: float,
           fraction: float, sample_rate_hz: float, dormant_class: str | None, training: dict,
           evaluation: dict | None = None, trigger: dict | None = None, early=None) -> Path:
    """One ONNX file via trainer.onnx_export, with the metadata the daemon needs (``trigger``: the
    settings to record; default the paper's threshold at ``fraction``)."""
    from trainer.model_meta import file_metadata
    from trainer.onnx_export import export_onnx

    meta = file_metadata(pads=pads, pad_sizes=pad_sizes, fullscale=fullscale,
                         trigger=dict(trigger) if trigger else {"fraction": float(fraction)},
                         sample_rate_hz=sample_rate_hz, dormant_class=dormant_class, training=training,
                         evaluation=evaluation)
    return export_onnx(model, path, meta, early=early)
