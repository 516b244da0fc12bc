"""Data set assembly: trigger position, the window, untriggered trials counted with reasons."""

from __future__ import annotations

import numpy as np
import pytest
from protocol_standin import standin_recordings

from firmware_io.layout import SensorLayout
from firmware_io.recordings.recording import Recording
from runtime.trigger import ThresholdTrigger
from runtime.trigger_settings import DEFAULT_HYSTERESIS
from trainer.dataset import (
    ABOVE_FROM_START,
    DatasetError,
    build_dataset,
    fingerprint,
    rising_trigger,
)


def _one_trial_recording(peak_at: int, value: int = 1000, n: int = 40) -> Recording:
    layout = SensorLayout.sdh2()
    frames = np.zeros((n, layout.n_taxels), dtype=np.uint16)
    col = int(layout.columns("distal")[50])
    frames[peak_at:, col] = value
    frames[:, int(layout.columns("proximal")[3])] = 4000  # a proximal pad far above the threshold
    fields = dict(subject="s1", object="ball", pose="up", action="push", run=0, extra={"onset": peak_at})
    return Recording.concatenate(layout, [(frames, np.arange(n) / 32.0, fields)])


def test_window_starts_at_the_trigger_of_the_chosen_pads_only():
    rec = _one_trial_recording(peak_at=12)
    ds = build_dataset([rec], T=15, pads="distal", fraction=0.15)
    assert ds.X.shape == (1, 3 * 78, 15) and ds.X.dtype == np.float32
    assert ds.trigger_offsets[0] == 12 and ds.onsets[0] == 12
    assert ds.X[0].max() == 1000 and ds.X[0, :, 0].max() == 1000
    # all pads: the proximal taxel at 4000 is above the level from the first frame: no rising edge
    ds_all = build_dataset([rec], T=15, pads="all", fraction=0.15)
    assert len(ds_all.y) == 0 and ds_all.untriggered[0].reason.startswith(ABOVE_FROM_START)


def test_fraction_is_configurable_and_untriggered_trials_are_reported():
    rec = _one_trial_recording(peak_at=5, value=500)  # 500 / 4095 = 12 %
    ds = build_dataset([rec], T=15, pads="distal", fraction=0.15)
    assert len(ds.y) == 0 and ds.n_untriggered == 1 and ds.n_trials == 1
    assert ds.untriggered[0].reason.startswith("never triggered")
    assert ds.X.shape == (0, 234, 15)
    assert len(build_dataset([rec], T=15, pads="distal", fraction=0.1).y) == 1


def test_too_late_trigger_is_not_padded():
    rec = _one_trial_recording(peak_at=30, n=40)
    ds = build_dataset([rec], T=15, pads="distal", fraction=0.15)
    assert ds.n_untriggered == 1 and ds.untriggered[0].reason.startswith("triggered too late")
    assert len(build_dataset([rec], T=10, pads="distal", fraction=0.15).y) == 1


def test_recorders_case_check_cuts_with_the_default_models_T(monkeypatch):
    """The recorder's check must follow the T `handover train` cuts with, not a copy of it."""
    from trainer import defaults
    from trainer.dataset import case_check, dataset_trigger

    rec = _one_trial_recording(peak_at=28, n=40)  # 12 frames from the trigger to the end
    frames, stamps = rec.trial_frames(rec.trials[0])
    for T, expected, at in ((10, None, 28), (20, "triggered too late", -1)):
        monkeypatch.setitem(defaults.DEFAULT_MODEL, "T", T)
        frame, why = case_check(dataset_trigger(fraction=0.15), pads="distal")(frames, stamps, rec.layout)
        assert (why if why is None else why.split(":")[0]) == expected and frame == at, (T, frame, why)


def test_standin_protocol_counts_every_trial():
    recs = standin_recordings(n_subjects=3, runs=2, silent=2, late=1)
    ds = build_dataset(recs, T=15, pads="distal", fraction=0.15)
    assert ds.n_trials == 3 * 2 * 4
    assert len(ds.y) + ds.n_untriggered == ds.n_trials and ds.n_untriggered == 3
    summary = ds.summary()
    assert summary["untriggered_reasons"] == {"never triggered": 2, "triggered too late": 1}
    assert sorted(set(ds.groups)) == ["s1", "s2", "s3"]
    assert ds.sample_rate_hz == pytest.approx(32.0)
    assert ds.subset(np.flatnonzero(ds.groups == "s2")).X.shape[0] == 8


def test_fingerprint_follows_frames_and_labels():
    recs = standin_recordings(n_subjects=1, runs=1)
    a = fingerprint(recs)
    assert a == fingerprint(standin_recordings(n_subjects=1, runs=1))
    rec = recs[0]
    relabelled = Recording(rec.layout, rec.frames, rec.timestamps,
                           [t.__class__(**{**t.to_dict(), "action": "hold"}) for t in rec.trials])
    assert fingerprint([relabelled]) != a


def test_bad_settings_are_clear_errors():
    recs = standin_recordings(n_subjects=1, runs=1)
    with pytest.raises(DatasetError, match="pad"):
        build_dataset(recs, pads="finger-7", fraction=0.15)
    with pytest.raises(DatasetError, match="fraction"):
        build_dataset(recs, fraction=1.5)


def _level_recording(levels: list[int], onset: int = 0) -> Recording:
    """One distal taxel following ``levels`` frame by frame."""
    layout = SensorLayout.sdh2()
    frames = np.zeros((len(levels), layout.n_taxels), dtype=np.uint16)
    frames[:, int(layout.columns("distal")[50])] = levels
    fields = dict(subject="s1", object="ball", pose="up", action="pull", run=0, extra={"onset": onset})
    return Recording.concatenate(layout, [(frames, np.arange(len(levels)) / 32.0, fields)])


def test_trial_above_the_level_from_its_first_frame_is_not_a_trigger():
    on = 0.15 * 4095  # 614
    ds = build_dataset([_level_recording([700] * 40)], T=15, pads="distal", fraction=0.15)
    assert len(ds.y) == 0 and ds.untriggered[0].reason.startswith(ABOVE_FROM_START)
    assert ds.summary()["untriggered_reasons"] == {ABOVE_FROM_START: 1}
    # dropping below the level but not below the re-arm level (10 % = 409) does not re-arm
    ds = build_dataset([_level_recording([700] * 5 + [500] * 5 + [700] * 30)], T=15, pads="distal", fraction=0.15)
    assert len(ds.y) == 0 and "never below the re-arm level" in ds.untriggered[0].reason
    # below the re-arm level, then up again: a rising edge, the trigger is there
    ds = build_dataset([_level_recording([700] * 5 + [300] * 5 + [700] * 30)], T=15, pads="distal", fraction=0.15)
    assert list(ds.trigger_offsets) == [10] and ds.untriggered == []
    # between the re-arm level and the level at the start: armed, fires when it reaches the level
    ds = build_dataset([_level_recording([500] * 3 + [int(on) + 1] * 37)], T=15, pads="distal", fraction=0.15)
    assert list(ds.trigger_offsets) == [3]


def test_dataset_trigger_is_the_runtime_trigger():
    """Fed frame by frame, the daemon's ThresholdTrigger (armed) fires where the data set says."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        levels = np.cumsum(rng.integers(-150, 151, size=60)).clip(0, 4095).astype(np.float32)[:, None]
        start, _ = rising_trigger(levels, 4095.0, 0.15)
        trig = ThresholdTrigger(1, 4095.0, fraction=0.15, hysteresis=DEFAULT_HYSTERESIS)
        trig.armed = bool(levels[0, 0] < trig.on_level)
        fired = [i for i in range(len(levels)) if trig.update(levels[i], i) >= 0]
        assert start == (fired[0] if fired else -1)
        if start > 0:
            assert levels[start - 1, 0] < trig.on_level <= levels[start, 0]  # a rising edge


def test_simulated_protocol_never_triggers_on_the_first_frame():
    from firmware_io.sim import simulate_protocol

    ds = build_dataset(simulate_protocol(seed=0, n_subjects=1, runs=2), T=15, pads="all", fraction=0.15)
    assert not np.any(ds.trigger_offsets == 0)
    assert ds.n_trials == 2 * 3 * 3 * 4


def test_windows_that_end_before_the_onset_are_counted():
    # trigger at frame 2, onset at frame 20: the 15 frames (2..16) end before the action starts
    early = _level_recording([0, 0] + [700] * 38, onset=20)
    ontime = _level_recording([0, 0] + [700] * 38, onset=10)
    ds = build_dataset([early, ontime], T=15, pads="distal", fraction=0.15)
    assert ds.windows_before_onset == 1
    assert ds.summary()["windows_before_onset"] == 1 and ds.summary()["n_cases_with_onset"] == 2
