"""Data set assembly: trigger position, the window, untriggered trials counted with reasons."""

from __future__ import annotations

import numpy as np
import pytest
from protocol_standin import standin_recordings

from firmware_io.layout import SensorLayout
from firmware_io.recording import Recording
from trainer.dataset import DatasetError, build_dataset, fingerprint, load_dataset, trigger_frame


def _one_trial_recording(peak_at: int, value: int = 1000, n: int = 40) -> Recording:
    layout = SensorLayout.sdh2()
    frames = np.zeros((n, layout.n_taxels), dtype=np.uint16)
    col = int(layout.columns("distal")[50])
    frames[peak_at:, col] = value
    frames[:, int(layout.columns("proximal")[3])] = 4000  # a proximal pad far above the threshold
    fields = dict(subject="s1", object="ball", pose="up", action="push", run=0, extra={"onset": peak_at})
    return Recording.concatenate(layout, [(frames, np.arange(n) / 32.0, fields)])


def test_trigger_frame_is_the_first_reaching_the_level():
    frames = np.array([[0, 10], [0, 600], [700, 0]])
    assert trigger_frame(frames, 600) == 1
    assert trigger_frame(frames, 701) == -1


def test_window_starts_at_the_trigger_of_the_chosen_pads_only():
    rec = _one_trial_recording(peak_at=12)
    ds = build_dataset([rec], T=15, pads="distal")
    assert ds.X.shape == (1, 3 * 78, 15) and ds.X.dtype == np.float32
    assert ds.trigger_offsets[0] == 12 and ds.onsets[0] == 12
    assert ds.X[0].max() == 1000 and ds.X[0, :, 0].max() == 1000
    # all pads: the proximal taxel at 4000 triggers at frame 0
    assert build_dataset([rec], T=15, pads="all").trigger_offsets[0] == 0


def test_fraction_is_configurable_and_untriggered_trials_are_reported():
    rec = _one_trial_recording(peak_at=5, value=500)  # 500 / 4095 = 12 %
    ds = build_dataset([rec], T=15, pads="distal", fraction=0.15)
    assert len(ds.y) == 0 and ds.n_untriggered == 1 and ds.n_trials == 1
    assert ds.untriggered[0].reason.startswith("never triggered")
    assert ds.X.shape == (0, 234, 15)
    assert len(build_dataset([rec], T=15, pads="distal", fraction=0.1).y) == 1


def test_too_late_trigger_is_not_padded():
    rec = _one_trial_recording(peak_at=30, n=40)
    ds = build_dataset([rec], T=15, pads="distal")
    assert ds.n_untriggered == 1 and ds.untriggered[0].reason.startswith("triggered too late")
    assert len(build_dataset([rec], T=10, pads="distal").y) == 1


def test_standin_protocol_counts_every_trial():
    recs = standin_recordings(n_subjects=3, runs=2, silent=2, late=1)
    ds = build_dataset(recs, T=15, pads="distal")
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


def test_bad_settings_are_clear_errors(tmp_path):
    recs = standin_recordings(n_subjects=1, runs=1)
    with pytest.raises(DatasetError, match="pad"):
        build_dataset(recs, pads="finger-7")
    with pytest.raises(DatasetError, match="fraction"):
        build_dataset(recs, fraction=1.5)
    with pytest.raises(ValueError, match=r"no \.hrec"):
        load_dataset(tmp_path)


def test_load_dataset_reads_a_folder(tmp_path):
    from protocol_standin import write_standin

    write_standin(tmp_path, n_subjects=2, runs=1)
    ds, recs = load_dataset(tmp_path, T=12, pads="distal")
    assert len(recs) == 2 and ds.X.shape[2] == 12 and ds.sources == ["subject_s1.hrec", "subject_s2.hrec"]
