"""A tiny synthetic stand-in for the simulated protocol (tests only; synthetic data).

Each trial is 3 s at 32 Hz on the SDH-2 layout: a light grip below the trigger level, then from
``onset`` a pressure pattern per action on the distal pads. Good enough to exercise the
trigger, the data set and the CLI; it makes no claim about real tactile data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from firmware_io.layout import SensorLayout
from firmware_io.recordings.recording import ACTIONS, Recording

RATE = 32.0


def _pattern(action: str, n: int, rng: np.random.Generator) -> np.ndarray:
    t = np.arange(n, dtype=float)
    amp = rng.uniform(1500, 3000)
    if action == "pull":
        return amp * np.clip(t / 10, 0, 1) * np.exp(-np.clip(t - 10, 0, None) / 8)
    if action == "push":
        return amp * np.clip(t / 4, 0, 1.5)
    if action == "hold":
        return amp * (1 - np.exp(-t / 3))
    return amp * np.exp(-0.5 * ((t - 3) / 1.5) ** 2)  # bump


def standin_recordings(
    n_subjects: int = 3, runs: int = 2, seed: int = 0, silent: int = 0, late: int = 0
) -> list[Recording]:
    """One recording per subject, 4 actions x runs trials each; ``silent``/``late`` trials of s1 never/late trigger."""
    layout = SensorLayout.sdh2()
    mask = layout.static_mask()
    distal_cols = layout.columns("distal")
    rng = np.random.default_rng(seed)
    out = []
    n = int(3 * RATE)
    for s in range(1, n_subjects + 1):
        segments = []
        k = 0
        for run in range(runs):
            for action in ACTIONS:
                onset = int(rng.integers(10, 30))
                frames = np.zeros((n, layout.n_taxels))
                frames[:, distal_cols[::7]] = 200.0
                contact = rng.choice(distal_cols, size=40, replace=False)
                kind = "normal"
                if s == 1 and k < silent:
                    kind = "silent"
                elif s == 1 and k < silent + late:
                    kind = "late"
                if kind != "silent":
                    start = n - 5 if kind == "late" else onset
                    pat = _pattern(action, n - start, rng)
                    frames[start:, contact] += pat[:, None] * rng.uniform(0.5, 1.0, size=len(contact))
                frames += rng.normal(0, 20, size=frames.shape)
                frames = np.clip(frames, 0, 4095) * mask
                stamps = (len(segments) * n + np.arange(n)) / RATE
                fields = dict(subject=f"s{s}", object="ball", pose="down", action=action, run=run,
                              extra={"onset": onset})
                segments.append((frames.astype(np.uint16), stamps, fields))
                k += 1
        out.append(Recording.concatenate(layout, segments, meta={"synthetic": True}))
    return out


def write_standin(folder: Path, **kw) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    return [rec.save(folder / f"subject_s{i + 1}.hrec") for i, rec in enumerate(standin_recordings(**kw))]
