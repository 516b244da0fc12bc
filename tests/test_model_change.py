"""A swap that changes the trigger, the pads or the classes is named from what to what."""

from __future__ import annotations

from runtime.config import TriggerConfig
from runtime.model_change import served, swap_warning, trigger_text
from runtime.trigger_settings import resolve_trigger

ONSET = resolve_trigger(None, {"kind": "onset"})
PAPER = resolve_trigger(None, {"fraction": 0.15})  # a model cut before the onset trigger: the paper's threshold
CLASSES = ("pull", "push", "hold", "bump")


def test_trigger_kind_pads_and_classes_changes_are_each_named():
    old = served(ONSET, (1, 3, 5), CLASSES)
    line = swap_warning("paper.onnx", old, served(PAPER, (0, 1, 2, 3, 4, 5), (*CLASSES, "dormant")))
    assert f"trigger onset (change {ONSET.change:g}, floor 0.25, back_frames 0, refractory_s 1.5) -> threshold (fraction 0.15" in line
    assert "pads [1, 3, 5] -> [0, 1, 2, 3, 4, 5]" in line
    assert "classes ['pull', 'push', 'hold', 'bump'] -> ['pull', 'push', 'hold', 'bump', 'dormant']" in line


def test_a_model_whose_windows_are_dated_back_is_named_beside_one_cut_at_the_trigger_frame():
    dated = resolve_trigger(None, {"kind": "onset", "back_frames": 3})
    line = swap_warning("new.onnx", served(ONSET, (1, 3, 5), CLASSES), served(dated, (1, 3, 5), CLASSES))
    assert "back_frames 0, refractory_s 1.5) -> onset (change 0.12, floor 0.25, back_frames 3," in line


def test_a_swap_that_changes_nothing_but_the_file_is_quiet_and_a_pinned_trigger_stays():
    old = served(ONSET, (1, 3, 5), CLASSES)
    assert swap_warning("same.onnx", old, served(ONSET, (1, 3, 5), CLASSES)) is None
    assert swap_warning("first.onnx", None, old) is None  # the first model: nothing to compare
    pinned = TriggerConfig(kind="onset")
    assert swap_warning("paper.onnx", old, served(resolve_trigger(pinned, {"fraction": 0.15}), (1, 3, 5), CLASSES)) is None
    assert "fraction 0.1 " not in trigger_text(PAPER) and trigger_text(None) is None
    higher = swap_warning("x", served(PAPER, (1,), CLASSES), served(resolve_trigger(None, {"fraction": 0.2}), (1,), CLASSES))
    assert "trigger threshold (fraction 0.15, hysteresis 0.05, refractory_s 1.5) -> threshold (fraction 0.2," in higher
