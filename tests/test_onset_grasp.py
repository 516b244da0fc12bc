"""The onset trigger fires only on an object held between fingers (``MIN_GRASP_FINGERS``; small synthetic streams)."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_io.layout import SensorLayout
from runtime.config import TriggerConfig
from runtime.onset import MIN_GRASP_FINGERS, OnsetTrigger
from runtime.trigger_settings import build_trigger, resolve_trigger
from tests.test_onset import CONTACT, PADS, RATE, fires, grasp_levels, rows_of

LAYOUT = SensorLayout.sdh2()


def _trigger(pad_sizes=PADS, pad_fingers=None) -> OnsetTrigger:
    return build_trigger(resolve_trigger(TriggerConfig(kind="onset")), pad_sizes, 4095.0, 15, RATE, pad_fingers)


def _push(levels: np.ndarray, pad: int, at: int = 200) -> np.ndarray:
    levels[at:, pad] *= 1.0 + 0.3 * np.clip((np.arange(len(levels) - at)) / 5.0, 0, 1)
    return levels


def test_sdh2_pads_pair_up_into_fingers():
    assert LAYOUT.pad_fingers("all") == (0, 0, 1, 1, 2, 2) and LAYOUT.pad_fingers("distal") == (0, 1, 2)
    assert [LAYOUT.finger_of(p) for p in LAYOUT.pads("thumb")] == [1, 1]
    odd = LAYOUT.subset("1,3,5")  # three matrices do not pair up: each is a finger of its own
    assert odd.pad_fingers("all") == (0, 1, 2)


def test_a_weight_on_one_pad_is_not_a_held_object():
    levels = _push(grasp_levels(300), pad=0)
    levels[:, 1:] = 0.0  # a calibration rig loads pad 0 alone; nothing touches the other fingers
    trig = _trigger()
    assert MIN_GRASP_FINGERS == 2 and fires(trig, rows_of(levels)) == [] and trig.not_held >= 1
    held = _trigger()  # the same push on an object held between fingers 0 and 2 fires
    two = _push(grasp_levels(300), pad=0)
    two[:, 1] = 0.0
    assert len(out := fires(held, rows_of(two))) == 1 and 200 <= out[0] <= 203 and held.grasp_fingers == 2


def test_two_pads_of_one_finger_are_one_finger():
    sizes = LAYOUT.pad_sizes("all")
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    levels = _push(grasp_levels(300), pad=0)
    rows = np.zeros((300, sum(sizes)), dtype=np.float32)
    for pad in (0, 1):  # proximal and distal pad of finger 0 press on something; fingers 1, 2 touch nothing
        rows[:, starts[pad] + 20:starts[pad] + 40] = levels[:, pad:pad + 1] if pad == 0 else levels[:, 1:2]
    as_fingers = _trigger(sizes, LAYOUT.pad_fingers("all"))
    assert fires(as_fingers, rows) == [] and as_fingers.grasp_fingers == 1
    as_pads = _trigger(sizes)  # without the fingers every pad counts as one: the rule cannot see it
    assert len(fires(as_pads, rows)) == 1


def test_a_tap_that_pushes_the_object_off_the_other_fingers_still_fires():
    levels = grasp_levels(300)
    levels[200:204, 0] *= 4.0  # the tap loads finger 0 ...
    levels[200:204, 1:] = 0.0  # ... and lifts the object off fingers 1 and 2 in the frame it fires
    trig = _trigger()
    assert len(out := fires(trig, rows_of(levels))) == 1 and out[0] == 200  # the settled grasp held it with three


def test_a_scene_of_one_finger_asks_for_one_finger():
    levels = _push(grasp_levels(300), pad=0)
    rows = rows_of(levels)[:, :78 * 2]  # the scene keeps the thumb's two pads only
    rows[:, 78 + 20:78 + 40] = 0.0
    thumb = _trigger((78, 78), LAYOUT.pad_fingers("thumb"))
    assert thumb.min_fingers == 1 and len(fires(thumb, rows)) == 1


def test_the_daemon_gives_the_trigger_the_fingers_of_its_pads(tmp_path):
    from tests.test_onset import _daemon

    daemon, _ = _daemon(tmp_path)
    fingers = daemon.detector.trigger._fingers.tolist()
    assert fingers == list(LAYOUT.pad_fingers(daemon.model.meta.pads)) and daemon.detector.trigger.min_fingers == 2


def test_contact_for_the_rule_is_a_patch_not_a_stray_taxel():
    levels = _push(grasp_levels(300), pad=0)
    levels[:, 1:] = 0.0
    rows = rows_of(levels)
    rows[:, CONTACT[1][:2]] = 5.0  # two stray loaded taxels on finger 1 (noise) are no contact
    trig = _trigger()
    assert fires(trig, rows) == [] and trig.grasp_fingers == 1


@pytest.mark.realdata
def test_a_real_calibration_rig_on_one_pad_does_not_fire(sdh2_data):
    """The rig loads weights onto one distal pad (a validation file of results/streams.md): a departure
    happens (the load rises by more than the change), but no object is held between fingers."""
    from firmware_io.recordings.importers import import_any

    rec = import_any(sdh2_data / "kiechle/pressure_profiles/calibration_sensitivity/sensitivity_0.1-1.0.dsa")
    pads = rec.layout.pads("all")
    trig = _trigger(rec.layout.pad_sizes(pads), rec.layout.pad_fingers(pads))
    rows = rec.frames[:, rec.layout.columns(pads)].astype(np.float32)
    assert fires(trig, rows) == [] and trig.not_held >= 1 and trig.grasp_fingers == 1
