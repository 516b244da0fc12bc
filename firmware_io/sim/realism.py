"""Statistics that compare recordings (real or synthetic) on what the simulator claims to model.

- noise floor: how often a taxel far from any contact reads non-zero, and the value it reads;
- contact values: quantiles of non-zero readings, the saturation ceiling, frame-to-frame
  change of loaded taxels (contact noise);
- frame timing: interval mean, spread, tails and lag-1 autocorrelation;
- contact area: non-zero taxels of a pad in contact;
- contact level: the peak reading of a pad in contact (how hard a hand's grasps read);
- ``shift``: how far two sources differ in noise floor and contact level (sizes lab B, ``sim.lab``).
numpy only, so the emulator side can use it too; the figure is benchmarks/studies/realism_plot.py.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from firmware_io.layout import SensorLayout
from firmware_io.recordings.importers.dsa import read_dsa
from firmware_io.recordings.recording import Recording

__all__ = ["contact_area", "contact_level", "frame_intervals", "load_real", "load_sources", "noise_floor",
           "real_dsa_files", "shift", "summarise"]

MAX_INTERVAL_S = 0.1
"""Intervals longer than this are recording pauses, not jitter."""
CONTACT_PAD_MIN = 100
"""A pad counts as in contact in a frame when its largest value reaches this."""
LOADED_MIN = 300
"""A taxel counts as loaded (for contact noise) at or above this value in two frames."""

REAL_31HZ_FOLDERS = ("grasps", "classification_video", "slip-detection", "room temperature")
"""Real .dsa folders recorded at the normal ~31 Hz rate with the threshold on (the
frequency_analysis and masked_matrix files run faster; the noise calibration runs with the
threshold off; they would not describe a normal stream)."""


def _pad_stack(frames: np.ndarray, layout: SensorLayout, pad: int) -> np.ndarray:
    m = layout.matrices[pad]
    return frames[:, layout.matrix_slice(pad)].reshape(len(frames), m.cells_y, m.cells_x)


def _near_contact(vals: np.ndarray, reach: int = 2) -> np.ndarray:
    """True where any *other* taxel within ``reach`` (Chebyshev) of the same frame is non-zero."""
    nz = (vals > 0).astype(np.int16)
    n, h, w = nz.shape
    # a box sum is separable: sum over rows, then over columns
    rows = np.zeros((n, h + 2 * reach, w), dtype=np.int16)
    rows[:, reach:reach + h] = nz
    col_sum = sum(rows[:, d:d + h] for d in range(2 * reach + 1))
    cols = np.zeros((n, h, w + 2 * reach), dtype=np.int16)
    cols[:, :, reach:reach + w] = col_sum
    count = sum(cols[:, :, d:d + w] for d in range(2 * reach + 1))
    return (count - nz) > 0


def noise_floor(frames: np.ndarray, layout: SensorLayout) -> dict:
    """Non-zero readings of taxels with no other non-zero taxel within 2 texels (same frame)."""
    isolated_nz, total, values = 0, 0, []
    for pad in range(layout.n_matrices):
        vals = _pad_stack(frames, layout, pad)
        exists = layout.matrices[pad].mask[None, :, :]
        untouched = ~_near_contact(vals) & exists
        total += int(untouched.sum())
        hit = untouched & (vals > 0)
        isolated_nz += int(hit.sum())
        values.append(vals[hit])
    v = np.concatenate(values) if values else np.zeros(0)
    return {
        "untouched_taxel_readings": total,
        "untouched_nonzero_fraction": isolated_nz / total if total else float("nan"),
        "untouched_nonzero_median": float(np.median(v)) if v.size else 0.0,
    }


def contact_values(frames: np.ndarray) -> dict:
    """Quantiles of non-zero readings, the ceiling, and the contact noise of loaded taxels."""
    nz = frames[frames > 0].astype(np.float64)
    q = np.percentile(nz, [5, 25, 50, 75, 95, 99]) if nz.size else np.full(6, np.nan)
    a, b = frames[:-1].astype(np.float64), frames[1:].astype(np.float64)
    loaded = (a >= LOADED_MIN) & (b >= LOADED_MIN)
    rel = np.abs(b - a)[loaded] / b[loaded]
    return {
        "nonzero_fraction": float(nz.size / frames.size) if frames.size else float("nan"),
        **{f"nonzero_p{p}": float(x) for p, x in zip((5, 25, 50, 75, 95, 99), q, strict=True)},
        "max": float(frames.max()) if frames.size else float("nan"),
        "loaded_rel_change_median": float(np.median(rel)) if rel.size else float("nan"),
    }


def frame_intervals(*timestamps: np.ndarray) -> dict:
    """Interval statistics in milliseconds over one or more stamp series (pauses > 100 ms left out)."""
    d = np.concatenate([np.diff(np.asarray(t, dtype=np.float64)) for t in timestamps])
    d = d[d < MAX_INTERVAL_S] * 1000.0
    if d.size < 3:
        return {"n": int(d.size)}
    return {
        "n": int(d.size), "mean_ms": float(d.mean()), "std_ms": float(d.std()),
        "p1_ms": float(np.percentile(d, 1)), "p99_ms": float(np.percentile(d, 99)),
        "min_ms": float(d.min()), "max_ms": float(d.max()),
        "outside_31_32_fraction": float(np.mean((np.round(d) < 31) | (np.round(d) > 32))),
        "lag1_corr": float(np.corrcoef(d[:-1], d[1:])[0, 1]),
    }


def contact_area(frames: np.ndarray, layout: SensorLayout) -> dict:
    """Non-zero taxels per pad while that pad is in contact (max >= CONTACT_PAD_MIN)."""
    areas = []
    for pad in range(layout.n_matrices):
        vals = frames[:, layout.matrix_slice(pad)]
        on = vals.max(axis=1) >= CONTACT_PAD_MIN
        areas.append((vals[on] > 0).sum(axis=1))
    a = np.concatenate(areas)
    if not a.size:
        return {"pad_frames_in_contact": 0}
    return {"pad_frames_in_contact": int(a.size), "area_median": float(np.median(a)),
            "area_p10": float(np.percentile(a, 10)), "area_p90": float(np.percentile(a, 90))}


def contact_level(frames: np.ndarray, layout: SensorLayout) -> dict:
    """Peak reading of each pad in each frame it is in contact (max >= CONTACT_PAD_MIN): median and p75.
    A peak, not the non-zero readings' median: a more sensitive pad lights more edge taxels with low
    values, which holds that median down however hard the grasp reads."""
    peaks = np.concatenate([frames[:, layout.matrix_slice(p)].max(axis=1) for p in range(layout.n_matrices)])
    peaks = peaks[peaks >= CONTACT_PAD_MIN]
    if not peaks.size:
        return {"pad_frames_in_contact": 0}
    return {"pad_frames_in_contact": int(peaks.size), "peak_median": float(np.median(peaks)),
            "peak_p75": float(np.percentile(peaks, 75))}


def shift(a: dict, b: dict) -> dict:
    """How far summary ``b`` sits from ``a``: ratios (b / a) of the noise floor (untouched taxels read
    non-zero) and of the contact level (pad peak median); ``*_factor`` is the ratio's size either way."""
    noise = b["noise"]["untouched_nonzero_fraction"] / a["noise"]["untouched_nonzero_fraction"]
    level = b["level"]["peak_median"] / a["level"]["peak_median"]
    return {"noise_floor_ratio": noise, "noise_floor_factor": max(noise, 1 / noise),
            "contact_level_ratio": level, "contact_level_factor": max(level, 1 / level)}


def summarise(recordings: Iterable[Recording]) -> dict:
    """All statistics over recordings pooled (intervals within each recording only)."""
    recs = list(recordings)
    layout = recs[0].layout
    frames = np.concatenate([r.frames for r in recs])
    return {
        "frames": len(frames),
        "noise": noise_floor(frames, layout),
        "values": contact_values(frames),
        "intervals": frame_intervals(*(r.timestamps for r in recs)),
        "area": contact_area(frames, layout),
        "level": contact_level(frames, layout),
    }


def real_dsa_files(folder: str | Path, names: Sequence[str] = REAL_31HZ_FOLDERS) -> list[Path]:
    """The real .dsa files of the chosen sub-folders (sorted)."""
    folder = Path(folder)
    return sorted(p for p in folder.rglob("*.dsa") if p.parent.name in names)


def load_real(folder: str | Path, names: Sequence[str] = REAL_31HZ_FOLDERS) -> list[Recording]:
    """Read the real reference recordings with the project's .dsa importer."""

    return [read_dsa(p) for p in real_dsa_files(folder, names)]


REAL_SOURCES = {"kiechle": "kiechle", "mas-group": "mas-group/slip_detection/bag"}
"""The two real SDH-2 sources under ``sdh2-dsa/`` (two labs, two hands): where their recordings are."""


def load_sources(sdh2_dsa: str | Path) -> dict[str, list[Recording]]:
    """Each real source's recordings (Kiechle's ~31 Hz .dsa files, mas-group's bags); empty when absent."""
    from firmware_io.recordings.importers import import_any

    root = Path(sdh2_dsa)
    return {"kiechle": load_real(root / REAL_SOURCES["kiechle"]),
            "mas-group": [import_any(p) for p in sorted((root / REAL_SOURCES["mas-group"]).glob("*.bag"))]}
