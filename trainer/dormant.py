"""A fifth class, "dormant": windows in which nobody interacts, so the runtime can classify every frame.

The paper suggests it to get rid of the manual threshold. A continuously classifying model
sees every T-frame window of the stream, so its training windows are cut the way the stream
will present them:

- *action* windows from the protocol's trials, at several positions around the annotated onset
  (from half a window of the action in view to a few frames after the onset), labelled with
  the action;
- *dormant* windows from the protocol's frames before the onset (the grasp baseline of every
  subject, object and pose) and from idle streams of the simulated hand (noise, creep, drift,
  the arm's motion, regrasps, the hand closing and opening, the open hand), stratified by what
  is going on so rare disturbances are represented.

Models are the unchanged BowSVC and the unchanged ONNX exporter; the 5-class model's metadata
names ``dormant_class`` so the daemon accepts it for ``scene.mode = "continuous"``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from firmware_io.recording import Recording
from trainer.dataset import fingerprint

DORMANT = "dormant"
ACTION_VIEW_MIN = 7
"""An action window shows at least this many frames from the onset (about half of T = 15)."""
ACTION_LATE_MAX = 4
"""... and starts at most this many frames after the onset."""
WINDOWS_PER_TRIAL = 3
IDLE_WINDOWS_PER_SOURCE = 250


@dataclass
class DormantDataset:
    """Cases ``X`` float32 ``(n, C, T)``, labels (four actions + dormant) and where each came from."""

    X: np.ndarray
    y: np.ndarray
    groups: np.ndarray
    """Subject for protocol windows, ``idle`` for idle-stream windows."""
    origin: np.ndarray
    """``action``, ``pre_onset`` or ``idle:<source>``."""
    pads: tuple[int, ...]
    pad_sizes: tuple[int, ...]
    T: int
    fullscale: float
    fingerprint: str

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
            for s in rng.choice(starts, size=min(per_trial, len(starts)), replace=False) if len(starts) else ():
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


def idle_windows(idle: Sequence[Recording], cols: np.ndarray, T: int, rng: np.random.Generator,
                 per_source: int = IDLE_WINDOWS_PER_SOURCE) -> tuple[list, list]:
    """Dormant windows from idle streams, up to ``per_source`` ending in each kind of idle frame."""
    ends: dict[str, list[tuple[int, int]]] = {}
    for r, rec in enumerate(idle):
        code = np.asarray(rec.meta["source_codes"])
        names = rec.meta["sources"]
        for k in range(T - 1, rec.n_frames):
            if code[k] >= 0:
                ends.setdefault(names[code[k]], []).append((r, k))
    X, origin = [], []
    for source in sorted(ends):
        pool = ends[source]
        for i in rng.choice(len(pool), size=min(per_source, len(pool)), replace=False):
            r, k = pool[i]
            X.append(idle[r].frames[k - T + 1:k + 1, cols].T)
            origin.append(f"idle:{source}")
    return X, origin


def build_dormant_dataset(protocol: Sequence[Recording], idle: Sequence[Recording], T: int = 15,
                          pads: str | Sequence[int] = "all", seed: int = 0,
                          per_source: int = IDLE_WINDOWS_PER_SOURCE) -> DormantDataset:
    """Five classes (the four actions + dormant) from the protocol and idle streams."""
    if not protocol:
        raise ValueError("no protocol recordings")
    layout = protocol[0].layout
    pad_idx = layout.pads(pads)
    cols = layout.columns(pad_idx)
    rng = np.random.default_rng(seed)
    X, y, groups, origin = protocol_windows(protocol, cols, T, rng)
    Xi, oi = idle_windows(idle, cols, T, rng, per_source)
    X += Xi
    y += [DORMANT] * len(Xi)
    groups += ["idle"] * len(Xi)
    origin += oi
    if not X:
        raise ValueError("no windows: trials lack onsets and no idle stream was given")
    return DormantDataset(
        X=np.asarray(X, dtype=np.float32).reshape(len(X), len(cols), T),
        y=np.asarray(y).astype(str), groups=np.asarray(groups).astype(str), origin=np.asarray(origin).astype(str),
        pads=tuple(pad_idx), pad_sizes=tuple(layout.pad_sizes(pad_idx)), T=int(T),
        fullscale=float(max(layout.matrices[p].fullscale for p in pad_idx)),
        fingerprint=fingerprint(list(protocol) + list(idle)),
    )


def train(X: np.ndarray, y: np.ndarray, K: int = 10, W: int = 7, kernel: str = "rbf", seed: int = 0):
    """The paper's estimator, unchanged (any number of classes)."""
    from trainer.classifier import BowSVC

    return BowSVC(n_words=K, window=W, kernel=kernel, random_state=seed).fit(X, y)


def export(model, path: str | Path, *, pads: Sequence[int], pad_sizes: Sequence[int], fullscale: float,
           fraction: float, sample_rate_hz: float, dormant_class: str | None, training: dict,
           evaluation: dict | None = None) -> Path:
    """One ONNX file via trainer.onnx_export, with the metadata the daemon needs."""
    from runtime import __version__
    from trainer.onnx_export import export_onnx

    meta = {
        "pads": [int(p) for p in pads],
        "pad_sizes": [int(s) for s in pad_sizes],
        "fullscale": float(fullscale),
        "trigger": {"fraction": float(fraction)},
        "sample_rate_hz": float(sample_rate_hz),
        "dormant_class": dormant_class,
        "training": {"project_version": __version__, "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **training},
        "evaluation": dict(evaluation or {}),
    }
    return export_onnx(model, path, meta)
