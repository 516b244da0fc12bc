"""``handover plot`` draws the trigger the model uses (its recorded kind and settings, its pads and
window), where the daemon's trigger would fire on that trial, and its legend sits beside the
curves. Data: a simulated protocol recording (synthetic); models from tests/tiny_models.py."""

from __future__ import annotations

import pytest

from firmware_io.sim import simulate_protocol
from runtime.cli import main as handover
from tests.tiny_models import tiny_model_bytes, write_model

pytest.importorskip("matplotlib")


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    (rec,) = simulate_protocol(seed=0, n_subjects=1, runs=1)
    path = tmp_path_factory.mktemp("rec") / "p.hrec"
    rec.save(path)
    return rec, path


def _model(tmp_path, trigger: dict, pads=(1, 3, 5)):
    return write_model(tmp_path, "m.onnx", tiny_model_bytes(pads=pads, trigger=trigger))


def test_the_models_trigger_is_drawn_not_the_papers(rec, tmp_path):
    from trainer.commands.plot_cli import model_trigger, trial_figure

    recording, _ = rec
    onset = model_trigger(recording, str(_model(tmp_path, {"kind": "onset", "fraction": 0.15})))
    threshold = model_trigger(recording, str(_model(tmp_path, {"kind": "threshold", "fraction": 0.05})))
    assert onset.settings.kind == "onset" and threshold.settings.kind == "threshold"
    assert onset.pads == (1, 3, 5) and onset.T == 15
    assert "onset trigger" in onset.label and "threshold trigger (5% of full scale" in threshold.label
    fired_onset = fired_threshold = 0
    for i in range(min(12, len(recording.trials))):
        frames, _ = recording.trial_frames(recording.trials[i])
        fired_onset += len(onset.fires(frames, recording.layout, 32.0))
        fired_threshold += len(threshold.fires(frames, recording.layout, 32.0))
    assert fired_onset and fired_threshold
    # the label on the figure is the model's trigger
    fig = trial_figure(recording, 0, onset)
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert any(label.startswith("onset trigger") for label in labels)
    assert not any("15% full scale" in label for label in labels)


@pytest.mark.parametrize("back_frames", [None, 3])
def test_the_drawn_window_is_where_the_training_windows_are_cut(rec, tmp_path, back_frames):
    """The same trigger object as the data set's (trainer.dataset.onset_start) on the same pads: the window the
    plot shades starts where training starts its case (dated back, for a model that records back_frames)."""
    from trainer.commands.plot_cli import model_trigger
    from trainer.dataset import onset_start

    recording, _ = rec
    recorded = {"kind": "onset", **({} if back_frames is None else {"back_frames": back_frames})}
    drawn = model_trigger(recording, str(_model(tmp_path, recorded)))
    layout = recording.layout
    dated = 0
    for trial in recording.trials:
        frames, _ = recording.trial_frames(trial)
        fires = drawn.fires(frames, layout, 32.0)
        first, _ = onset_start(frames[:, layout.columns(drawn.pads)], layout.pad_sizes(drawn.pads), layout.fullscale,
                               drawn.settings, drawn.T, 32.0, layout.pad_fingers(drawn.pads))
        assert (fires[0][1] if fires else -1) == first
        dated += bool(fires) and fires[0][1] < fires[0][0]
    assert bool(dated) == bool(back_frames), dated  # a model cut at the trigger frame is never dated back


def test_the_legend_does_not_cover_the_curves(rec, tmp_path):
    from trainer.commands.plot_cli import model_trigger, trial_figure

    recording, path = rec
    fig = trial_figure(recording, 0, model_trigger(recording, None))
    fig.canvas.draw()
    ax = fig.axes[0]
    legend = ax.get_legend().get_window_extent()
    plot_area = ax.get_window_extent()
    assert not legend.overlaps(plot_area), (legend, plot_area)
    png = tmp_path / "t.png"
    assert handover(["plot", str(path), "--trial", "1", "--model", str(_model(tmp_path, {"kind": "onset"})),
                     "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert handover(["plot", str(path), "--model", str(tmp_path / "nope.onnx"), "--out", str(png)]) == 2
