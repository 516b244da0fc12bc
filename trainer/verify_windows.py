"""The windows ``handover verify`` runs graph and reference on, as a stream of batches.

Held-out trials (the user's recordings, or a simulated protocol the training did not see) are
cut into every ``stride``-th T-frame window of each trial and handed out ``BATCH`` windows at a
time, so memory stays bounded (a few MB) however many windows there are; the count is known
up front for the progress line. The stress families follow as one more batch source.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trainer.verify import BATCH, VerifyError

__all__ = ["recording_stream", "simulated_stream", "stress_windows", "trained_data_folder"]


@dataclass
class WindowStream:
    """``batches()`` yields (float32 ``[n, T, C]``, source names); ``total`` windows in all."""

    recordings: list
    meta: object
    stride: int
    source: str

    @property
    def total(self) -> int:
        T = self.meta.T
        return sum(len(range(0, t.n_frames - T + 1, self.stride))
                   for rec in self.recordings for t in rec.trials)

    def batches(self, batch: int = BATCH) -> Iterator[tuple[np.ndarray, list[str]]]:
        T = self.meta.T
        pending: list[np.ndarray] = []
        for rec in self.recordings:
            cols = rec.layout.columns(list(self.meta.pads))
            for trial in rec.trials:
                frames, _ = rec.trial_frames(trial)
                sel = frames[:, cols]
                for s in range(0, len(sel) - T + 1, self.stride):
                    pending.append(np.asarray(sel[s : s + T], dtype=np.float32))
                    if len(pending) == batch:
                        yield np.stack(pending), [self.source] * batch
                        pending = []
        if pending:
            yield np.stack(pending), [self.source] * len(pending)


def _stream(recordings: list, meta, stride: int, source: str) -> WindowStream:
    stream = WindowStream(recordings, meta, stride, source)
    if stream.total == 0:
        raise VerifyError(f"the {source} have no trial of at least T={meta.T} frames")
    return stream


def simulated_stream(meta, seed: int, n_subjects: int, stride: int) -> WindowStream:
    """Held-out trials of the simulated protocol (a seed the training did not use)."""
    from firmware_io.sim import simulate_protocol

    recs = simulate_protocol(seed=seed, n_subjects=n_subjects)
    return _stream(recs, meta, stride, "simulated (synthetic) recordings")


def recording_stream(folder: str | Path, meta, stride: int) -> WindowStream:
    from firmware_io.recordings.recording import RecordingError, find_recordings, load_all

    try:
        recs = load_all(find_recordings(folder))
    except (OSError, RecordingError) as exc:
        raise VerifyError(str(exc)) from exc
    if not recs:
        raise VerifyError(f"no recordings in {folder}")
    return _stream(recs, meta, stride, f"recordings in {Path(folder).name}")


def trained_data_folder(meta) -> Path | None:
    """The folder of recordings the model was trained on, as ``handover train --data`` recorded it."""
    folder = (meta.training or {}).get("data_folder")
    return Path(folder) if folder else None


def stress_windows(model, meta, seed: int = 0) -> tuple[np.ndarray, list[str]]:
    """The stress families of ``trainer.stress`` (a few hundred windows) and their names."""
    from trainer.stress import stress_cases

    bow = getattr(model, "bow_", None)
    # a flattened-series SVM has no codebook: windows between two arbitrary "codewords" still stress it
    codebook = bow.codebook_ if bow is not None else np.eye(2, max(1, min(5, meta.T - 1))) * 100.0
    families = stress_cases(meta.T, meta.n_channels, codebook, seed)
    frames = np.concatenate(list(families.values()))
    names = [f"stress:{name}" for name, arr in families.items() for _ in range(len(arr))]
    return frames, names
