"""Labelled tasks built from the real SDH-2 recordings in ``../shared/data`` (other projects',
GPL-3.0; labels by file), each with its split written down.

Window rule (documented, not tuned): a frame is *in contact* when a taxel of the task's pads reaches
``CONTACT_FRACTION`` of full scale; contact runs are cut into chunks of at most ``CHUNK_FRAMES``, and a
case is T consecutive frames inside one chunk, every ``STRIDE`` frames. A chunk is all train or all
test, so overlapping windows never straddle the split; where one file holds one class, splits keep
chunks apart (``real_objects_across_folders`` keeps files apart). The tasks: ``real_tasks``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = [
    "CHUNK_FRAMES", "CONTACT_FRACTION", "FULLSCALE", "STRIDE", "RealTask", "T",
    "cut_windows", "grouped_task", "real_tasks", "temporal_blocks"
]

T = 15
STRIDE = 8
CHUNK_FRAMES = 96
CONTACT_FRACTION = 0.05
FULLSCALE = 4095.0
DISTAL = (1, 3, 5)
ALL_PADS = (0, 1, 2, 3, 4, 5)


@dataclass
class RealTask:
    name: str
    description: str
    X: np.ndarray
    y: np.ndarray
    chunks: np.ndarray
    files: np.ndarray
    pad_sizes: tuple[int, ...]
    pad_shapes: list[tuple[int, int]]
    splits: list  # of trainer.evaluation.Split
    split_rule: str


def cut_windows(rec, pads, chunk_prefix: str, n_frames: int = T, stride: int = STRIDE) -> tuple[np.ndarray, np.ndarray]:
    """Cases ``(n, C, n_frames)`` float32 from one recording by the documented rule (a case every
    ``stride`` frames), and their chunk ids."""
    cols = rec.layout.columns(list(pads))
    frames = rec.frames[:, cols].astype(np.float32)
    contact = frames.max(axis=1) >= CONTACT_FRACTION * FULLSCALE
    cases, chunk_ids = [], []
    n_chunk = 0
    i = 0
    while i < len(frames):
        if not contact[i]:
            i += 1
            continue
        j = i
        while j < len(frames) and contact[j]:
            j += 1
        for start in range(i, j, CHUNK_FRAMES):
            stop = min(j, start + CHUNK_FRAMES)
            for s in range(start, stop - n_frames + 1, stride):
                cases.append(frames[s : s + n_frames].T)
                chunk_ids.append(f"{chunk_prefix}#{n_chunk}")
            n_chunk += 1
        i = j
    if not cases:
        return np.zeros((0, len(cols), n_frames), np.float32), np.zeros(0, dtype=object)
    return np.stack(cases), np.asarray(chunk_ids, dtype=object)


def load_windows(paths: dict[str, Path | list[Path]], pads, n_frames: int = T, stride: int = STRIDE) -> tuple:
    """Windows of every file (label = key; a key may name several files): X, y, chunk ids, file
    names, pad sizes, pad shapes."""
    from firmware_io.recordings.importers import import_any

    Xs, ys, chunks, files = [], [], [], []
    layout = None
    for label, given in paths.items():
        for path in given if isinstance(given, list) else [given]:
            rec = import_any(path)
            layout = rec.layout
            X, ch = cut_windows(rec, pads, path.name, n_frames, stride)
            Xs.append(X)
            ys += [label] * len(X)
            chunks.append(ch)
            files += [path.name] * len(X)
    sizes = tuple(layout.pad_sizes(list(pads)))
    shapes = [(layout.matrices[p].cells_y, layout.matrices[p].cells_x) for p in pads]
    return np.concatenate(Xs), np.asarray(ys), np.concatenate(chunks), np.asarray(files), sizes, shapes


def grouped_task(name: str, description: str, paths: dict[str, Path | list[Path]], pads, seed: int,
                 n_folds: int = 3, n_frames: int = T, stride: int = STRIDE, min_chunks: int = 0) -> RealTask:
    """A task split by ``n_folds``-fold StratifiedGroupKFold over contact chunks; classes with fewer
    than ``min_chunks`` contact chunks are left out (they cannot be both trained and tested)."""
    from sklearn.model_selection import StratifiedGroupKFold

    from trainer.evaluation import Split

    X, y, ch, files, sizes, shapes = load_windows(paths, pads, n_frames, stride)
    kept = [c for c in np.unique(y) if len(set(ch[y == c].tolist())) >= min_chunks]
    left_out = sorted(str(c) for c in np.unique(y) if c not in kept)
    keep = np.isin(y, kept)
    X, y, ch, files = X[keep], y[keep], ch[keep], files[keep]
    cv = StratifiedGroupKFold(n_splits=n_folds, shuffle=True, random_state=seed)
    splits = [Split(f"fold {i}", tr, te) for i, (tr, te) in enumerate(cv.split(X, y, ch))]
    rule = f"{n_folds}-fold StratifiedGroupKFold over contact chunks (a chunk is all train or all test)"
    if n_frames != T:
        rule += f"; cases of {n_frames} frames every {stride} frames"
    if min_chunks:
        rule += f"; objects with at least {min_chunks} contact chunks"
        if left_out:
            rule += f" (left out: {', '.join(left_out)})"
    return RealTask(name, description, X, y, ch, files, sizes, shapes, splits, rule)


def _across_folders(video: Path, grasps: Path) -> RealTask:
    from trainer.evaluation import Split

    pairs = {"foam": ("foam.dsa", "foam_ball.dsa"), "hockey": ("hockey.dsa", "hockey_ball.dsa"),
             "teapot": ("utah_teapot.dsa", "teapot_handle.dsa")}
    Xa, ya, cha, fa, sizes, shapes = load_windows({k: video / a for k, (a, _) in pairs.items()}, DISTAL)
    Xb, yb, chb, fb, _, _ = load_windows({k: grasps / b for k, (_, b) in pairs.items()}, DISTAL)
    ia, ib = np.arange(len(Xa)), len(Xa) + np.arange(len(Xb))
    splits = [Split("train classification_video, test grasps", ia, ib),
              Split("train grasps, test classification_video", ib, ia)]
    return RealTask("real_objects_across_folders",
                    "foam / hockey ball / teapot: classification_video/ files against grasps/ files",
                    np.concatenate([Xa, Xb]), np.concatenate([ya, yb]), np.concatenate([cha, chb]),
                    np.concatenate([fa, fb]), sizes, shapes, splits,
                    "files apart: train on one folder, test on the other, both ways")


def _slip_bags(bags: Path) -> RealTask:
    from trainer.evaluation import Split

    paths = {n: bags / f"{n}.bag" for n in ("no_slippage", "slip_down", "slip_up")}
    X, y, ch, files, sizes, shapes = load_windows(paths, ALL_PADS)
    blocks = temporal_blocks(y, ch, SLIP_FOLDS)
    splits = [Split(f"time block {i + 1} of {SLIP_FOLDS}", np.flatnonzero(blocks != i), np.flatnonzero(blocks == i))
              for i in range(SLIP_FOLDS)]
    return RealTask("real_slip", "mas-group bags no_slippage / slip_down / slip_up (one file each, all pads)",
                    X, y, ch, files, sizes, shapes, splits, SLIP_SPLIT)


SLIP_FOLDS = 3
SLIP_SPLIT = (f"temporal blocks: each file's contact chunks in time order cut into {SLIP_FOLDS} consecutive blocks; "
              f"fold i tests block i of every file and trains on the rest (every chunk is tested once)")
"""real_slip's split. Until 2026-11-24 it was one split (first 60 % of each file's chunks train, the rest
test), decided by one test chunk (results/slip_diagnosis.md); blocked folds keep time order inside each
block and test every chunk once, so the figure has a spread. Thin all the same:
slip_down has two chunks, so the third block tests none of it, and the task rests on eight chunks."""


def class_chunks(y: np.ndarray, chunks: np.ndarray) -> dict:
    """Each class's chunk ids in order of appearance (one file per class here, so time order)."""
    return {label: list(dict.fromkeys(chunks[y == label].tolist())) for label in dict.fromkeys(y.tolist())}


def temporal_blocks(y: np.ndarray, chunks: np.ndarray, n_blocks: int) -> np.ndarray:
    """Block number of every window: each class's chunks (``class_chunks``) cut into ``n_blocks``
    consecutive runs (``np.array_split``)."""
    out = np.empty(len(y), dtype=int)
    for order in class_chunks(y, chunks).values():
        for b, part in enumerate(np.array_split(np.arange(len(order)), n_blocks)):
            for k in part:
                out[chunks == order[k]] = b
    return out


LONG_FRAMES, LONG_STRIDE, LONG_FOLDS = 30, 15, 5
"""``real_objects_long``: the shape of task a new user tries first (many objects, distal pads, a few dozen
frames per case, 5-fold), kept honest by grouping the folds by contact chunk."""


def _objects_long(by_stem: dict[str, Path], grasps: Path, seed: int) -> RealTask:
    """Every object of classification_video/ and grasps/ (the foam and the hockey ball, recorded in
    both folders, are one class each), cases of ``LONG_FRAMES`` frames."""
    same = {"foam_ball": "foam", "hockey_ball": "hockey"}
    paths: dict[str, list[Path]] = {stem: [p] for stem, p in by_stem.items()}
    for p in sorted(grasps.glob("*.dsa")):
        paths.setdefault(same.get(p.stem, p.stem), []).append(p)
    task = grouped_task("real_objects_long", "", paths, DISTAL, seed, n_folds=LONG_FOLDS, n_frames=LONG_FRAMES,
                        stride=LONG_STRIDE, min_chunks=LONG_FOLDS)
    task.description = (f"{len(set(task.y.tolist()))} objects of kiechle classification_video/ and grasps/ (foam and "
                        "hockey ball from both folders; one class each), distal pads, longer cases")
    return task


SLIP_SCENES = ("slip_examples_pen_and_wooden_block", "slip_hockey_ball", "slip_test", "slip_test2")
"""kiechle slip-detection/ recordings with enough contact chunks for a grouped 3-fold split;
slip_and_rotation_teapot_handle has a single chunk and is left out."""


def real_tasks(data_dir: Path, seed: int = 0) -> tuple[list[RealTask], list[str]]:
    """The labelled tasks found under ``data_dir`` (``.../shared/data``) and notes on what is absent."""
    root = Path(data_dir) / "sdh2-dsa"
    profiles = root / "kiechle" / "pressure_profiles"
    video, grasps, slips = profiles / "classification_video", profiles / "grasps", profiles / "slip-detection"
    bags = root / "mas-group" / "slip_detection" / "bag"
    by_stem = {p.stem: p for p in sorted(video.glob("*.dsa"))} if video.is_dir() else {}
    builders: list[tuple[str, bool, Callable[[], RealTask]]] = [
        ("real_objects", bool(by_stem), lambda: grouped_task(
            "real_objects", f"{len(by_stem)} objects of kiechle classification_video/ (one file each, distal pads)",
            by_stem, DISTAL, seed)),
        ("real_objects_all_pads", bool(by_stem), lambda: grouped_task(
            "real_objects_all_pads", f"the same {len(by_stem)} objects, all six pads", by_stem, ALL_PADS, seed)),
        ("real_grasps", grasps.is_dir(), lambda: grouped_task(
            "real_grasps", "kiechle grasps/ by object (5 files, one object each, all pads)",
            {p.stem: p for p in sorted(grasps.glob("*.dsa"))}, ALL_PADS, seed)),
        ("real_slip_scenes", all((slips / f"{n}.dsa").is_file() for n in SLIP_SCENES), lambda: grouped_task(
            "real_slip_scenes", "kiechle slip-detection/ by recording (4 slip scenes: pen and wooden block, hockey "
            "ball, slip_test, slip_test2; one file each, distal pads)",
            {n: slips / f"{n}.dsa" for n in SLIP_SCENES}, DISTAL, seed)),
        ("real_objects_across_folders", bool(by_stem) and grasps.is_dir(), lambda: _across_folders(video, grasps)),
        ("real_objects_long", bool(by_stem) and grasps.is_dir(), lambda: _objects_long(by_stem, grasps, seed)),
        ("real_slip", all((bags / f"{n}.bag").is_file() for n in ("no_slippage", "slip_down", "slip_up")),
         lambda: _slip_bags(bags)),
    ]
    tasks, notes = [], []
    for name, present, build in builders:
        if present:
            tasks.append(build())
        else:
            notes.append(f"{name} skipped: its recordings are not under {root}")
    return tasks, notes
