"""Every stream setting says what it costs on real signals: the model's ``real_false_events`` metadata
(runtime/model_meta.py) round-trips, and ``handover inspect`` / ``handover run --check`` say when the model is
served in a setting whose false events per hour on real idle are unmeasured or above 1 per hour, not below."""

from __future__ import annotations

import pytest

from runtime.cli import main as handover
from runtime.model_meta import REAL_FALSE_KEY
from tests.tiny_models import CLASSES, tiny_model_bytes, write_model

pytest.importorskip("onnx")

BELOW = {"per_hour": 0.4, "events": 1, "hours": 2.5, "data": "held-out real idle"}
ABOVE = {"per_hour": 155.7, "events": 463, "hours": 2.97, "data": "the real recordings"}


def _model(folder, measured: dict | None, name: str = "m.onnx"):
    folder.mkdir(exist_ok=True)
    extra = {REAL_FALSE_KEY: measured} if measured is not None else {}
    data = tiny_model_bytes(classes=(*CLASSES, "dormant"), dormant_class="dormant", trigger={"kind": "onset"},
                            extra=extra)
    return write_model(folder, name, data)


def test_the_key_round_trips_and_a_broken_entry_reads_unmeasured(tmp_path):
    from runtime.model import load_model
    from runtime.model_meta import real_false_events

    table = {"onset_dormant": BELOW, "continuous": ABOVE, "onset": {"per_hour": "many"}, "threshold": 3}
    meta = load_model(_model(tmp_path / "m", table), warm_up=False).meta
    assert real_false_events(meta) == {"onset_dormant": BELOW, "continuous": ABOVE}
    junk = load_model(_model(tmp_path / "j", "not a table"), warm_up=False).meta  # loads; reads as unmeasured
    assert real_false_events(junk) == {}


def test_the_trainer_writes_the_key_only_from_real_idle():
    from trainer.own_replay import _real_part, real_false_meta

    part = {"events": [], "delays": [], "early": 0, "references": [], "period": 0.03125, "false_by_class": {},
            "idle_frames": {"quiet": 115200}, "false_by_source": {"quiet": 1}, "false_by_source_arm_messages": None}
    assert _real_part([{**part, "synthetic": True}], "onset_dormant") is None
    real = _real_part([{**part, "synthetic": False}, {**part, "synthetic": True}], "onset_dormant")
    assert real["recordings"] == 1 and real["hours"] == pytest.approx(1.0) and real["per_hour"] == pytest.approx(1.0)
    entry = real_false_meta({"real_idle": real})[REAL_FALSE_KEY]["onset_dormant"]
    assert entry["events"] == 1 and "held-out replay" in entry["data"]
    assert real_false_meta({"real_idle": None}) == {} == real_false_meta(None)
    both = _real_part([{**part, "synthetic": False}], "onset_dormant", [(2.0, 280), (0.5, 0)])
    table = real_false_meta({"real_idle": both})[REAL_FALSE_KEY]
    assert set(table) == {"onset_dormant", "continuous"} and table["continuous"]["per_hour"] == pytest.approx(112.0)
    assert table["continuous"]["hours"] == pytest.approx(2.5) and table["continuous"]["events"] == 280


def test_inspect_says_unmeasured_and_above_not_below(tmp_path, capsys):
    assert handover(["inspect", str(_model(tmp_path / "a", {"onset_dormant": BELOW, "continuous": ABOVE}))]) == 0
    out = capsys.readouterr().out
    warnings = [line for line in out.splitlines() if line.startswith("  warning: stream setting")]
    assert len(warnings) == 1 and "continuous: false events 155.89/h (463 in 2.97 h)" in warnings[0], out
    assert "above 1 per hour" in warnings[0] and "serve onset_dormant (0.40/h (1 in 2.50 h))" in warnings[0]
    assert "  real idle: onset_dormant false events 0.40/h (1 in 2.50 h): held-out real idle" in out
    assert handover(["inspect", str(_model(tmp_path / "b", None))]) == 0
    out = capsys.readouterr().out
    warnings = [line for line in out.splitlines() if line.startswith("  warning: stream setting")]
    assert [w.split(":")[1].split()[-1] for w in warnings] == ["onset_dormant", "continuous"]
    assert all("unmeasured" in w and "handover record --device URL --idle-only" in w for w in warnings)


@pytest.mark.parametrize(("mode", "measured", "said"), [
    ("trigger", {"onset_dormant": BELOW, "continuous": ABOVE}, None),
    ("continuous", {"onset_dormant": BELOW, "continuous": ABOVE}, "continuous: false events 155.89/h (463 in 2.97 h)"),
    ("trigger", None, "onset_dormant: false events on real idle signals unmeasured"),
    ("continuous", {"continuous": ABOVE}, 'continuous: false events 155.89/h (463 in 2.97 h) on real idle signals ('
     'the real recordings), above 1 per hour; serve it with the trigger ([scene] mode = "trigger")'),
    ("trigger", {"onset_dormant": {**BELOW, "per_hour": 1.6, "events": 4}}, "onset_dormant: false events 1.60/h (4 in 2.50 h)"),
    ("trigger", {"onset_dormant": {**BELOW, "per_hour": 0.0, "events": 0, "hours": 0.15}},
     "onset_dormant: 0 false events in only 0.15 h of real idle"),
])
def test_check_says_it_for_the_served_setting(tmp_path, capsys, mode, measured, said):
    models = tmp_path / "models"
    _model(models, measured)
    config = tmp_path / "handover.toml"
    config.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\n[scene]\nmode = "{mode}"\n')
    assert handover(["run", "--config", str(config), "--check"]) == 0
    out = capsys.readouterr()
    assert "would serve model" in out.out
    lines = [line for line in out.err.splitlines() if "stream setting" in line]
    if said is None:
        assert lines == [], out.err
    else:
        assert len(lines) == 1 and lines[0].startswith(f"handover run: warning: stream setting {said}"), out.err


def test_train_console_says_whether_real_idle_was_measured():
    from trainer.own_replay import replay_lines

    hours = 0.2
    base = {"folds": [{}], "reference": ["onset"], "events": 0, "idle_hours": hours, "false_events": 1,
            "false_per_hour": 1 / hours, "idle_by_source": {"quiet": {"hours": hours, "false_events": 1}}}
    assert "real idle signals: none (every idle recording is synthetic)" in replay_lines(base)[-1]
    real = {"mode": "onset_dormant", "recordings": 2, "hours": hours, "events": 1, "per_hour": 5.0}
    line = replay_lines({**base, "real_idle": real})[-1]
    assert line.startswith("real idle signals (2 recordings not synthetic): false events 5.00/h (1 in 0.2 h) in onset_dormant")


@pytest.mark.realdata
def test_train_writes_the_figure_from_real_idle_and_inspect_shows_it(tmp_path, capsys):
    """A real recording imported as idle beside scripted subjects: the model file carries its held-out replay on
    those real signals (the subjects' own idle is synthetic and does not count)."""
    from runtime.model import load_model
    from runtime.model_meta import real_false_events
    from tests.conftest import real_data_dir

    real = real_data_dir() / "kiechle" / "pressure_profiles" / "calibration_noise" / "temperature-noise.dsa"
    data = tmp_path / "data"
    for name, seed in (("s1", 0), ("s2", 1)):
        assert handover(["record", "--device", f"subject://?seed={seed}&speed=max", "--subject", name, "--out",
                         str(data), "--poses", "down", "--objects", "ball", "--runs", "2", "--auto", "--gap", "0",
                         "--countdown", "0", "--quiet", "--no-look", "--idle-minutes", "0"]) == 0
    assert handover(["import", str(real), "--out", str(data), "--idle", "quiet", "--subject", "s1"]) == 0
    report = tmp_path / "report"
    assert handover(["train", "--data", str(data), "--out", str(report), "--no-sweep", "--repeats", "2",
                     "--early", "off", "--no-real-idle", "--quiet"]) == 0
    carried = real_false_events(load_model(report / "model.onnx", warm_up=False).meta)
    assert carried, "the real idle's figure is written into the model"
    for entry in carried.values():
        assert entry["hours"] > 0 and "held-out replay of 1 real recording" in entry["data"]
    capsys.readouterr()
    assert handover(["inspect", str(report / "model.onnx")]) == 0
    out = capsys.readouterr().out
    assert all(f"  real idle: {setting} " in out for setting in carried)
