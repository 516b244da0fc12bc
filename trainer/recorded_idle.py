"""A lab's own idle recordings in training: dormant windows from recorded idle stretches.

With idle stretches (``handover record``, ``handover import --idle``) ``handover train`` adds the class
"dormant", so the exported model is the one the default stream setting serves. ``trainer.dormant``
owns how dormant windows are cut; this module only splits a recording into its continuous idle pieces
and names each window's subject. Without idle data one line says what that costs
(results/streams.json).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from firmware_io.recordings.idle_stretches import has_idle, stretches_of
from firmware_io.recordings.recording import Recording
from trainer.dormant import DORMANT

__all__ = ["add_idle", "idle_only_problem", "idle_pieces", "subject_of", "too_few_line"]

STREAMS_RESULTS = Path(__file__).resolve().parents[1] / "results" / "streams.json"
"""Where ``./dev bench streams`` writes the measured stream figures (a source checkout)."""


DORMANT_CUTS = ("trigger", "in_view", "both")
"""How dormant windows are cut from recorded idle (both ways owned by ``trainer.dormant``): where the
model's own trigger fires on the idle stretches (``trigger_windows``: the windows a trigger-mode
model is asked about while nobody interacts), every window stratified by the idle source in view
(``idle_windows``, as ``./dev bench dormant`` trains for continuous mode), or both."""
DORMANT_CUT = "trigger"
"""The cut ``handover train`` uses; chosen by the rule of ``benchmarks.streams_own`` on validation
streams (results/streams_own.md), never on the demo's session or the test streams."""
MIN_DORMANT_WINDOWS = 10
"""Fewer dormant windows than this make no class (the same floor as any training: trainer.pipeline.MIN_CASES)."""
DORMANT_PER_SOURCE = 60
"""``in_view``: dormant windows per idle source in view."""


@dataclass
class IdleWindows:
    """Dormant windows ``X`` ``(n, C, T)`` from recorded idle, their subject and idle source, and notes."""

    X: np.ndarray
    groups: np.ndarray
    origin: np.ndarray
    seconds: float
    cut: str = DORMANT_CUT
    notes: list[str] = field(default_factory=list)
    """One line per thing the user should know (a stretch too short for a window, ...)."""

    @property
    def makes_class(self) -> bool:
        """Whether there are enough windows for a dormant class (``MIN_DORMANT_WINDOWS``)."""
        return len(self.X) >= MIN_DORMANT_WINDOWS

    @property
    def per_source(self) -> dict[str, int]:
        names, counts = np.unique(self.origin, return_counts=True)
        return {str(n): int(c) for n, c in zip(names, counts, strict=True)}


def subject_of(rec: Recording, fallback: str) -> str:
    """The subject a recording belongs to (its trials', its metadata's, else ``fallback``)."""
    if rec.trials:
        return rec.trials[0].subject
    subject = rec.meta.get("subject") if isinstance(rec.meta, dict) else None
    return str(subject) if subject else fallback


def idle_pieces(rec: Recording) -> list[tuple[int, int, str]]:
    """Continuous idle parts ``(first, last, what)`` of a recording: each recorded stretch, else each
    run of source-coded frames (a simulated or imported idle stream; ``-1`` frames are trials)."""
    stretches = stretches_of(rec.meta)
    if stretches:
        return [(int(s["first"]), int(s["last"]), f"idle stretch {int(s.get('index', k)) + 1} ({s['source']})")
                for k, s in enumerate(stretches)]
    if not has_idle(rec.meta):
        return []
    code = np.asarray(rec.meta["source_codes"], dtype=np.int64)
    idle = np.concatenate([[False], code >= 0, [False]])
    edges = np.flatnonzero(np.diff(idle.astype(np.int8)))
    return [(int(a), int(b) - 1, "idle stream") for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _piece(rec: Recording, first: int, last: int) -> Recording:
    sl = slice(first, last + 1)
    codes = np.asarray(rec.meta["source_codes"], dtype=np.int64)[sl]
    return Recording(rec.layout, rec.frames[sl], rec.timestamps[sl], [],
                     {"sources": list(rec.meta["sources"]), "source_codes": codes.tolist()})


def recorded_idle_windows(recordings: Sequence[Recording], names: Sequence[str], ds, seed: int,
                          cut: str = DORMANT_CUT, per_source: int = DORMANT_PER_SOURCE) -> IdleWindows | None:
    """Dormant windows of every recording's idle pieces for the data set ``ds`` (its pads, T and
    trigger), cut as ``cut`` says (``DORMANT_CUTS``); None: no recording holds idle.

    A piece shorter than a window gives none and is named in ``notes``; nothing else is lost."""
    from trainer.dormant import idle_windows, trigger_windows

    if cut not in DORMANT_CUTS:
        raise ValueError(f"dormant cut {cut!r}: one of {', '.join(DORMANT_CUTS)}")
    T = ds.T
    pieces, groups, notes = [], [], []
    seconds = 0.0
    for rec, name in zip(recordings, names, strict=True):
        subject = subject_of(rec, Path(name).stem)
        period = rec.period_s()
        for first, last, what in idle_pieces(rec):
            n = last - first + 1
            seconds += n * period
            if n < T:
                notes.append(f"{name}: {what} has {n} frames, shorter than a window ({T} frames): no dormant "
                             "window from it (record stretches of a few seconds)")
                continue
            pieces.append(_piece(rec, first, last))
            groups.append(subject)
    if not pieces and not notes:
        return None
    layout = recordings[0].layout
    cols = layout.columns(list(ds.pads))
    X, origin, window_groups = [], [], []
    if pieces and cut in ("trigger", "both"):
        x, o, g = trigger_windows(pieces, cols, T, ds.trigger, ds.pad_sizes, ds.fullscale,
                                  layout.pad_fingers(list(ds.pads)), group_of=groups)
        X, origin, window_groups = X + x, origin + o, window_groups + g
    if pieces and cut in ("in_view", "both"):
        x, o, g = idle_windows(pieces, cols, T, np.random.default_rng(seed), per_source, group_of=groups)
        X, origin, window_groups = X + x, origin + o, window_groups + g
    return IdleWindows(X=np.asarray(X, dtype=np.float32).reshape(len(X), len(cols), T),
                       groups=np.asarray(window_groups, dtype=object).astype(str),
                       origin=np.asarray(origin, dtype=object).astype(str), seconds=seconds, cut=cut, notes=notes)


def idle_only_problem(recordings: Sequence[Recording], names: Sequence[str]) -> str | None:
    """One line when no recording holds a trial but some hold idle: there is nothing to learn actions from."""
    if any(rec.trials for rec in recordings):
        return None
    idle = [n for rec, n in zip(recordings, names, strict=True) if idle_pieces(rec)]
    if not idle:
        return None
    return (f"{len(idle)} recording{'s' if len(idle) != 1 else ''} hold only idle stretches and none holds a trial: "
            "the model needs the four actions too; record subjects with `handover record` (without --idle-only) "
            "into the same folder, then train again (the idle recordings are kept and used)")


def no_dormant_cost(streams_json: Path = STREAMS_RESULTS) -> str | None:
    """The one figure for what a model without a dormant class costs, as the docs quote it, from the
    measured false events per hour (onset against onset_dormant); None without the results file."""
    try:
        fph = json.loads(Path(streams_json).read_text())["sim_false_per_hour"]
        four, five = float(fph["onset"]), float(fph["onset_dormant"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return (f"raises {four:.0f} false events per hour of synthetic idle (the test streams' idle stream and the idle "
            f"between events) against {five:.0f} with a dormant class")


def no_idle_line(streams_json: Path = STREAMS_RESULTS) -> str:
    """What a model without a dormant class costs on a live stream, from the measured figures."""
    how = ("record idle with `handover record` (a few minutes per subject by default; `--idle-only` for a long "
           "session) or `handover import --idle`, then train again")
    if (cost := no_dormant_cost(streams_json)) is None:
        return f"no idle recordings: the model has no dormant class and reports more false events while the arm moves; {how}"
    return f"no idle recordings: the model has no dormant class; that setting (onset) {cost} (results/streams.json); {how}"


def with_dormant(ds, idle: IdleWindows):
    """The data set ``ds`` (trigger-cut trial cases) plus the dormant windows, as one data set."""
    from trainer.dataset import Dataset

    n = len(idle.X)
    return Dataset(
        X=np.concatenate([ds.X, idle.X]) if n else ds.X,
        y=np.concatenate([ds.y, np.full(n, DORMANT)]).astype(str),
        groups=np.concatenate([ds.groups, idle.groups]).astype(str),
        objects=np.concatenate([ds.objects, np.full(n, "-")]).astype(str),
        poses=np.concatenate([ds.poses, idle.origin]).astype(str),
        runs=np.concatenate([ds.runs, np.zeros(n, dtype=np.int64)]),
        trigger_offsets=np.concatenate([ds.trigger_offsets, np.full(n, -1, dtype=np.int64)]),
        onsets=np.concatenate([ds.onsets, np.full(n, -1, dtype=np.int64)]),
        untriggered=ds.untriggered, layout=ds.layout, pads=ds.pads, pad_sizes=ds.pad_sizes, T=ds.T,
        fraction=ds.fraction, fullscale=ds.fullscale, sample_rate_hz=ds.sample_rate_hz, fingerprint=ds.fingerprint,
        hysteresis=ds.hysteresis, trigger=ds.trigger)


def too_few_line(seconds: float, n_windows: int, cut: str) -> str:
    """What recorded idle with too few dormant windows costs and what to do (train's warning, report.md)."""
    from trainer.data_warnings import MORE_IDLE

    return (f"{seconds / 60:.1f} min of recorded idle gave {n_windows} dormant windows (cut: {cut}; at least "
            f"{MIN_DORMANT_WINDOWS} make the class): the model has no dormant class; record more idle: {MORE_IDLE}")


def add_idle(ds, recordings: Sequence[Recording], names: Sequence[str], seed: int, say: Callable[[str], None],
             cut: str = DORMANT_CUT, warn: Callable[[str], None] | None = None):
    """``(data set with dormant windows, IdleWindows)``; ``(ds, None)`` and the one line saying what a
    model without them costs when nothing holds idle; ``(ds, idle)`` and a line saying to record more
    when the idle gives too few windows (``idle.makes_class`` is False). ``say``: progress; ``warn``:
    lines about the data to see even when quiet."""
    warn = warn or say
    idle = recorded_idle_windows(recordings, names, ds, seed, cut)
    if idle is None:
        say(no_idle_line())
        return ds, None
    for note in idle.notes:
        warn(note)
    if not idle.makes_class:
        warn(too_few_line(idle.seconds, len(idle.X), cut))
        return ds, idle
    from trainer.data_warnings import idle_kinds_text

    say(f"{idle.seconds / 60:.1f} min of recorded idle: {len(idle.X)} dormant windows "
        f"({idle_kinds_text(idle.per_source)})")
    return with_dormant(ds, idle), idle
