"""From recordings to classifier input: the daemon's trigger finds each trial's start, T frames follow.

Train and serve must cut the same windows, so the trigger's settings come from the runtime's
``resolve_trigger`` and each labelled trial is fed frame by frame to the runtime's own trigger object;
a case is the T frames from where the trigger dates the departure (``back_frames``) and ``pre_frames`` before
that, as in the daemon. The onset trigger
(the default) is told at a trial's first frame that the grasp has settled; the threshold trigger fires
on a rising edge only. A trial that never triggers, or ends before T frames after its trigger, is
listed in ``Dataset.untriggered`` with the reason: never dropped silently, never padded.
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from firmware_io.errors import HandoverError
from firmware_io.layout import SensorLayout
from firmware_io.recordings.recording import Recording, Trial
from firmware_io.trigger_level import is_trigger_level
from runtime.training_counts import TrainingCounts
from runtime.trigger import ThresholdTrigger
from runtime.trigger_settings import (
    DEFAULT_HYSTERESIS,
    PAPER_FRACTION,
    TriggerSettings,
    build_trigger,
    capped_hysteresis,
    resolve_trigger,
)

__all__ = [
    "ABOVE_FROM_START", "DECIDED_START", "TOO_EARLY", "TOO_LATE", "Dataset", "DatasetError", "build_dataset", "case_check",
    "dataset_trigger", "fingerprint", "frames_before_trigger", "onset_start", "reason_counts", "rising_trigger",
    "untriggered_lines"
]

DECIDED_START = "decided_start"
"""``trial.extra`` key of a trial whose case is the window a daemon decided on (a captured event,
trainer.field_folder): its first frame within the trial. Its label is about that window, so it is cut
there, not where the trigger fires on the shorter captured stretch (a third of them fired at their first
frames, without the grasp the daemon had seen settle)."""
ABOVE_FROM_START = "above the level from the first frame"
NEVER = "never triggered"
TOO_LATE = "triggered too late"
TOO_EARLY = "triggered too early"


class DatasetError(HandoverError, ValueError):
    """Recordings that cannot make a data set (no trials, different sensors, bad settings)."""


@dataclass(frozen=True)
class SkippedTrial:
    """A labelled trial that gave no case, and why."""

    subject: str
    object: str
    pose: str
    action: str
    run: int
    reason: str

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Dataset:
    """Cases ``X`` float32 ``(n_cases, n_channels, T)`` with their labels and provenance."""

    X: np.ndarray
    y: np.ndarray
    groups: np.ndarray
    """Subject of each case (the unit of leave-one-subject-out)."""
    objects: np.ndarray
    poses: np.ndarray
    runs: np.ndarray
    trigger_offsets: np.ndarray
    """Frame (within its trial) where each case starts."""
    onsets: np.ndarray
    """Annotated action onset within the trial (``trial.extra["onset"]``), -1 when unknown."""
    untriggered: list[SkippedTrial]
    layout: SensorLayout
    pads: tuple[int, ...]
    pad_sizes: tuple[int, ...]
    T: int
    fraction: float
    fullscale: float
    sample_rate_hz: float
    fingerprint: str
    hysteresis: float = DEFAULT_HYSTERESIS
    """Re-arm below ``(fraction - hysteresis)`` x full scale (the runtime trigger's rule)."""
    trigger: TriggerSettings = field(default_factory=lambda: dataset_trigger(fraction=PAPER_FRACTION))
    """What cut the windows (recorded in the model's metadata, so the daemon cuts the same)."""

    @property
    def n_trials(self) -> int:
        """Labelled trials seen, cases plus skipped (dormant windows from idle recordings are no trials; an
        event a person labelled dormant in review is one)."""
        return int(np.sum(~self._idle_windows)) + len(self.untriggered)

    @property
    def _idle_windows(self) -> np.ndarray:
        """Which cases are dormant windows cut from idle (no trial's: ``trigger_offsets`` -1)."""
        from trainer.dormant import DORMANT

        return (self.y == DORMANT) & (self.trigger_offsets < 0)

    @property
    def n_untriggered(self) -> int:
        return len(self.untriggered)

    def counts(self) -> TrainingCounts:
        """Trials and windows as every report of this data set states them (dormant windows are no trials)."""
        return TrainingCounts(trials=self.n_trials, windows=len(self.y), untriggered=self.n_untriggered,
                              dormant=int(np.sum(self._idle_windows)))

    @property
    def classes(self) -> list[str]:
        return sorted(set(self.y.tolist()))

    def subset(self, index: np.ndarray) -> Dataset:
        """The same data set restricted to some cases (skipped trials kept for the record)."""
        return replace(self, **{name: getattr(self, name)[index] for name in
                                 ("X", "y", "groups", "objects", "poses", "runs", "trigger_offsets", "onsets")})

    @property
    def windows_before_onset(self) -> int:
        """Cases whose T frames all precede the annotated action onset (they cannot see the action)."""
        known = self.onsets >= 0
        return int(np.sum(known & (self.trigger_offsets + self.T - 1 < self.onsets)))

    def summary(self) -> dict:
        """Counts for reports: cases per class and subject, skipped trials and why."""
        reasons = dict(reason_counts(self.untriggered))
        known = self.onsets >= 0
        delay = (self.trigger_offsets[known] - self.onsets[known]) if known.any() else np.zeros(0)
        return {
            **self.counts().to_meta(),
            "untriggered_reasons": reasons,
            "per_class": {c: int(np.sum(self.y == c)) for c in self.classes},
            "per_subject": {s: int(np.sum(self.groups == s)) for s in sorted(set(self.groups.tolist()))},
            "trigger_minus_onset_frames": ({"median": float(np.median(delay)), "min": int(delay.min()),
                                           "max": int(delay.max())} if len(delay) else None),
            "n_cases_with_onset": int(np.sum(known)),
            "windows_before_onset": self.windows_before_onset,
            "pads": list(self.pads),
            "pad_sizes": list(self.pad_sizes),
            "T": self.T,
            "trigger_fraction": self.fraction,
            "trigger_hysteresis": self.hysteresis,
            "trigger": self.trigger.to_meta(),
            "trigger_rule": ONSET_RULE if self.trigger.kind == "onset" else THRESHOLD_RULE,
            "fullscale": self.fullscale,
            "sample_rate_hz": self.sample_rate_hz,
            "fingerprint": self.fingerprint,
        }


ONSET_RULE = ("runtime.onset.OnsetTrigger: armed on the trial's first frame (a settled grasp), fires when a pad's "
              "summed pressure departs from the tracked grasp; the window starts where the departure began "
              "(back_frames) and pre_frames before that")
THRESHOLD_RULE = ("runtime.trigger.ThresholdTrigger: rising edge; a trial above the level from its first frame "
                  "triggers only after dropping below the re-arm level")


def reason_counts(skipped) -> Counter:
    """How many trials gave no case for each kind of reason (the text before its first colon)."""
    return Counter(s.reason.split(":")[0] for s in skipped)


def untriggered_lines(ds: Dataset) -> list[str]:
    """One line per class whose trials gave no case: how many, why, and what a recording needs."""
    lines = []
    for action in sorted({s.action for s in ds.untriggered}):
        skipped = [s for s in ds.untriggered if s.action == action]
        why = reason_counts(skipped)
        total = len(skipped) + int(np.sum(ds.y == action))
        causes = "; ".join(f"{n} {key} ({_cause(key, ds)})" for key, n in sorted(why.items()))
        lines.append(f"{action}: {len(skipped)} of {total} trials gave no case: {causes}")
    return lines


def _cause(reason: str, ds: Dataset) -> str:
    """What a trial skipped for ``reason`` lacks, for the trigger that cut the data set."""
    onset = ds.trigger.kind == "onset"
    if reason == TOO_LATE:
        return (f"fewer than T={ds.T} frames after the trigger: the action came late in the trial or the trial "
                "stops too soon after go (handover record --trial-seconds)")
    if reason == TOO_EARLY:
        return "the window starts before the trial: record the held grasp before go (handover record --lead-in)"
    if reason == ABOVE_FROM_START:
        return (f"the held grasp already presses above {ds.fraction:g} x full scale, so there is no rising edge: "
                "use --trigger onset or a higher --fraction")
    if onset:
        return (f"no pad departed by {ds.trigger.change:.0%} from the held grasp: the person did not act, or the "
                "object was not held still before go")
    return f"the pads never reached {ds.fraction:g} x full scale: a light grasp or a pull; use --trigger onset"


def dataset_trigger(kind: str | None = None, fraction: float | None = None,
                    hysteresis: float = DEFAULT_HYSTERESIS) -> TriggerSettings:
    """The trigger that cuts training windows: ``kind`` if given; an explicit ``fraction`` alone
    means the paper's threshold at that level; else the daemon's default (``resolve_trigger``)."""
    from runtime.config import TriggerConfig

    if kind is None and fraction is not None:
        kind = "threshold"
    if fraction is not None and not is_trigger_level(fraction):
        raise DatasetError(f"trigger fraction must be in (0, 1), got {fraction}")
    if hysteresis < 0:
        raise DatasetError(f"trigger hysteresis must be >= 0, got {hysteresis}")
    return resolve_trigger(TriggerConfig(kind=kind, fraction=fraction, hysteresis=float(hysteresis)))


def onset_start(frames: np.ndarray, pad_sizes: Sequence[int], fullscale: float, settings: TriggerSettings,
                T: int, rate_hz: float, pad_fingers: Sequence[int] | None = None) -> tuple[int, str | None]:
    """(frame the daemon's onset trigger dates its window from within this trial, or -1; why not, or None).

    The trigger is told the grasp is settled at the first frame (a protocol trial starts on the
    held object); a trial that starts with an empty hand is settled by the trigger itself.
    """
    trig = build_trigger(settings, tuple(pad_sizes), fullscale, T, rate_hz, pad_fingers)
    trig.set_grasp(True)
    rows = frames.astype(np.float32)
    for i in range(len(rows)):
        if trig.update(rows[i], i) >= 0:
            return i - trig.back, None
    return -1, f"{NEVER}: no pad departed by {settings.change:.0%} from the settled grasp"


def rising_trigger(frames: np.ndarray, fullscale: float, fraction: float, hysteresis: float = DEFAULT_HYSTERESIS
                   ) -> tuple[int, str | None]:
    """(frame where the runtime's trigger fires within this trial, or -1; why not, or None).

    Frames are fed to ``runtime.trigger.ThresholdTrigger`` one by one. The trigger starts armed
    unless the first frame is already at or above the level (a trial is not its own rising edge).
    """
    if frames.size == 0:
        return -1, f"{NEVER}: no frames"
    levels = frames.max(axis=1).astype(np.float32)
    trig = ThresholdTrigger(1, fullscale, fraction=fraction, hysteresis=capped_hysteresis(fraction, hysteresis),
                            window=2)
    trig.armed = bool(levels[0] < trig.on_level)
    started_above = not trig.armed
    for i in range(len(levels)):
        if trig.update(levels[i : i + 1], i) >= 0:
            return i, None
    if started_above:
        rearmed = bool((levels < trig.off_level).any())
        return -1, (f"{ABOVE_FROM_START}: {int(levels[0])} >= {trig.on_level:.0f}, "
                    + ("no rising edge after re-arming" if rearmed else
                       f"never below the re-arm level {trig.off_level:.0f}"))
    return -1, f"{NEVER}: max {int(levels.max())} < {trig.on_level:.0f}"


def fingerprint(recordings: Sequence[Recording]) -> str:
    """sha256 over every recording's layout, frames, timestamps and trial labels (order matters)."""
    h = hashlib.sha256()
    for rec in recordings:
        h.update(json.dumps(rec.layout.to_dict(), sort_keys=True).encode())
        h.update(np.ascontiguousarray(rec.frames, dtype="<u2").tobytes())
        h.update(np.ascontiguousarray(rec.timestamps, dtype="<f8").tobytes())
        labels = [{k: v for k, v in t.to_dict().items() if k != "extra"} for t in rec.trials]
        h.update(json.dumps(labels, sort_keys=True).encode())
    return h.hexdigest()


def build_dataset(
    recordings: Sequence[Recording],
    T: int = 15,
    pads: str | Sequence[int] = "all",
    fraction: float | None = None,
    hysteresis: float = DEFAULT_HYSTERESIS,
    trigger: TriggerSettings | None = None,
) -> Dataset:
    """Cut one case per labelled trial: the runtime's trigger within the trial, then T frames of the chosen pads.

    ``trigger``: the settings to cut with; None takes ``dataset_trigger(fraction=fraction,
    hysteresis=hysteresis)`` (an explicit fraction = the paper's threshold, else the daemon's default)."""
    if T < 2:
        raise DatasetError(f"T must be at least 2 frames, got {T}")
    settings = trigger if trigger is not None else dataset_trigger(fraction=fraction, hysteresis=hysteresis)
    fraction = settings.fraction
    if not recordings:
        raise DatasetError("no recordings")
    layout = recordings[0].layout
    try:
        pad_idx = layout.pads(pads)
    except ValueError as exc:
        raise DatasetError(str(exc)) from None
    shapes = [(layout.matrices[p].cells_y, layout.matrices[p].cells_x) for p in pad_idx]
    for i, rec in enumerate(recordings[1:], start=1):
        other = [(rec.layout.matrices[p].cells_y, rec.layout.matrices[p].cells_x)
                 for p in pad_idx if p < rec.layout.n_matrices]
        if other != shapes:
            raise DatasetError(f"recording {i}: its pads {list(pad_idx)} differ from the first recording's")
    fullscale = max(layout.matrices[p].fullscale for p in pad_idx)
    hysteresis = settings.hysteresis  # capped by resolve_trigger, as the daemon's
    cols = layout.columns(pad_idx)
    pad_sizes = layout.pad_sizes(pad_idx)

    cases, labels, skipped = [], [], []
    intervals = []
    acting = any(rec.trials for rec in recordings)
    for rec in recordings:  # the rate of the trials' recordings: imported idle at another rate must not set it
        if rec.n_frames > 1 and (rec.trials or not acting):
            intervals.append(rec.sample_interval())
        rate = 1.0 / rec.period_s()
        for trial in rec.trials:
            window = _cut(rec, trial, cols, rate, settings, (pad_sizes, layout.pad_fingers(pad_idx)), fullscale,
                          hysteresis, T)
            if isinstance(window, str):
                skipped.append(SkippedTrial(trial.subject, trial.object, trial.pose, trial.action, trial.run, window))
                continue
            start, frames = window
            cases.append(frames.T)
            onset = trial.extra.get("onset") if isinstance(trial.extra, dict) else None
            labels.append((trial, start, _relative_onset(onset, trial)))
    if not cases and not skipped:
        raise DatasetError("the recordings hold no labelled trials (imported .dsa files and bags have none): "
                           "record subjects with `handover record`, or run `./dev bench compare` to train "
                           "and evaluate on the real SDH-2 recordings, which are labelled by file")
    n_ch = len(cols)
    X = np.asarray(cases, dtype=np.float32).reshape(len(cases), n_ch, T)
    rate = float(1.0 / np.median(intervals)) if intervals else float("nan")
    return Dataset(
        X=X,
        y=np.asarray([t.action for t, _, _ in labels], dtype=object).astype(str),
        groups=np.asarray([t.subject for t, _, _ in labels], dtype=object).astype(str),
        objects=np.asarray([t.object for t, _, _ in labels], dtype=object).astype(str),
        poses=np.asarray([t.pose for t, _, _ in labels], dtype=object).astype(str),
        runs=np.asarray([t.run for t, _, _ in labels], dtype=np.int64),
        trigger_offsets=np.asarray([s for _, s, _ in labels], dtype=np.int64),
        onsets=np.asarray([o for _, _, o in labels], dtype=np.int64),
        untriggered=skipped,
        layout=layout,
        pads=tuple(pad_idx),
        pad_sizes=layout.pad_sizes(pad_idx),
        T=int(T),
        fraction=float(fraction),
        fullscale=float(fullscale),
        sample_rate_hz=rate,
        fingerprint=fingerprint(recordings),
        hysteresis=hysteresis,
        trigger=settings,
    )


@dataclass(frozen=True)
class CaseCheck:
    """For the recorder: ``check(frames, stamps, layout)`` -> (the frame the trigger dates the departure from,
    None) when ``build_dataset`` would cut a case from this one trial, else (-1, its reason). It runs
    ``build_dataset`` itself, so the recorder marks the frame training cuts at; ``str(check)`` names the cut (stored with each trial)."""

    settings: TriggerSettings
    T: int
    pads: str | tuple[int, ...] = "all"

    def __call__(self, frames: np.ndarray, stamps: np.ndarray, layout: SensorLayout) -> tuple[int, str | None]:
        if len(frames) == 0:
            return -1, "no frames"
        trial = Trial("check", "-", "-", "-", 0, 0, len(frames) - 1)
        rec = Recording(layout=layout, frames=frames, timestamps=np.asarray(stamps, dtype=np.float64),
                        trials=[trial])
        ds = build_dataset([rec], T=self.T, pads=self.pads, trigger=self.settings)
        if ds.untriggered:
            return -1, ds.untriggered[0].reason
        return int(ds.trigger_offsets[0]) + frames_before_trigger(self.settings, self.T), None

    def __str__(self) -> str:
        level = f" at {self.settings.fraction:.0%}" if self.settings.kind == "threshold" else ""
        pads = self.pads if isinstance(self.pads, str) else ",".join(map(str, self.pads))
        return f"{self.settings.name} trigger{level}, T={self.T}, pads {pads}"


def case_check(settings: TriggerSettings | None = None, T: int | None = None,
               pads: str | Sequence[int] = "all") -> CaseCheck:
    """The recorder's check with what ``handover train`` cuts with by default: ``dataset_trigger()``
    and the default model's T, unless given."""
    from trainer.defaults import DEFAULT_MODEL

    return CaseCheck(settings if settings is not None else dataset_trigger(),
                     int(DEFAULT_MODEL["T"]) if T is None else int(T), pads if isinstance(pads, str) else tuple(pads))


def frames_before_trigger(settings: TriggerSettings, T: int) -> int:
    """Where a case's window starts: ``pre_frames`` before the trigger frame, as the daemon cuts, within T."""
    return min(int(settings.pre_frames), T - 1)


def _cut(rec: Recording, trial: Trial, cols: np.ndarray, rate_hz: float, settings: TriggerSettings,
         pads: tuple[tuple[int, ...], tuple[int, ...]], fullscale: float, hysteresis: float, T: int
         ) -> tuple[int, np.ndarray] | str:
    """One trial -> (window start, T frames) or the reason there is none, with the daemon's trigger
    (``pads``: the selected pads' column counts and fingers)."""
    frames, _ = rec.trial_frames(trial)
    selected = frames[:, cols]
    decided = trial.extra.get(DECIDED_START) if isinstance(trial.extra, dict) else None
    if isinstance(decided, int) and not isinstance(decided, bool):
        if not 0 <= decided <= len(selected) - T:
            return f"{TOO_LATE}: the decided window starts at frame {decided} of {len(selected)}, {T} frames needed"
        return decided, selected[decided : decided + T]
    if settings.kind == "onset":
        trig, why = onset_start(selected, pads[0], fullscale, settings, T, rate_hz, pads[1])
    else:
        trig, why = rising_trigger(selected, fullscale, settings.fraction, hysteresis)
    if trig < 0:
        return str(why)
    start = trig - frames_before_trigger(settings, T)
    if start < 0:
        return f"{TOO_EARLY}: frame {trig}, {trig - start} frames before it needed"
    if start + T > len(selected):
        return f"{TOO_LATE}: frame {trig} of {len(selected)}, {T} frames needed"
    return start, selected[start : start + T]


def _relative_onset(onset, trial: Trial) -> int:
    """Onset within the trial (the protocol's convention); an absolute index inside the trial is converted.

    Only used for the report's trigger-minus-onset statistic; -1 when unknown.
    """
    if onset is None:
        return -1
    onset = int(onset)
    if 0 <= onset < trial.n_frames:
        return onset
    if trial.first <= onset <= trial.last:
        return onset - trial.first
    return -1

