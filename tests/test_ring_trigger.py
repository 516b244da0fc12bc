"""Ring buffer wrap-around and the threshold trigger's hysteresis, refractory time and baseline."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_io.layout import SensorLayout
from runtime.ring import RingBuffer, column_runs
from runtime.trigger import ContinuousTrigger, ThresholdTrigger


def test_column_runs_of_distal_pads():
    layout = SensorLayout.sdh2()
    runs = column_runs(layout.columns("distal"))
    assert len(runs) == 3
    assert runs[0] == (84, 162, 0, 78)


@pytest.mark.parametrize("capacity", [15, 16, 40])
def test_window_is_the_last_frames_across_many_wraps(capacity):
    layout = SensorLayout.sdh2()
    cols = layout.columns("distal")
    ring = RingBuffer(cols, capacity)
    rng = np.random.default_rng(1)
    frames = rng.integers(0, 4096, size=(5 * capacity + 7, layout.n_taxels), dtype=np.uint16)
    for i, f in enumerate(frames):
        ring.push(f, i)
        n = min(i + 1, 15, capacity)
        w = ring.window(n)
        assert w.shape == (1, n, cols.size) and w.dtype == np.float32
        assert w.flags["C_CONTIGUOUS"]
        np.testing.assert_array_equal(w[0], frames[i + 1 - n : i + 1][:, cols].astype(np.float32))
        np.testing.assert_array_equal(ring.latest(), frames[i, cols])
    # an earlier window (ending 3 frames ago)
    w = ring.window(5, end_offset=3)
    np.testing.assert_array_equal(w[0], frames[-8:-3][:, cols])


def test_window_refuses_more_than_held():
    ring = RingBuffer(np.arange(4), 8)
    ring.push(np.arange(10, dtype=np.uint16))
    with pytest.raises(ValueError, match="needs"):
        ring.window(2)
    with pytest.raises(ValueError, match="capacity"):
        ring.window(9)


def test_resized_keeps_history():
    ring = RingBuffer(np.arange(3), 4)
    for i in range(10):
        ring.push(np.full(5, i, dtype=np.uint16), i)
    big = ring.resized(8)
    np.testing.assert_array_equal(big.window(4)[0, :, 0], [6, 7, 8, 9])
    big.push(np.full(5, 10, dtype=np.uint16), 10)
    np.testing.assert_array_equal(big.window(5)[0, :, 0], [6, 7, 8, 9, 10])


def _run(trigger, levels, n_channels=4):
    row = np.zeros(n_channels, dtype=np.float32)
    dues = []
    for i, level in enumerate(levels):
        row[:] = 0
        row[i % n_channels] = level
        due = trigger.update(row, i)
        if due >= 0:
            dues.append((i, due))
    return dues


def test_threshold_fires_once_per_touch_with_hysteresis():
    trig = ThresholdTrigger(4, fullscale=1000, fraction=0.15, hysteresis=0.05, refractory_frames=0, window=15)
    # rises over 150, wobbles between 100 and 150 (stays triggered), drops below 100, rises again
    levels = [0, 50, 160, 140, 120, 149, 101, 160, 90, 0, 155, 0]
    assert _run(trig, levels) == [(2, 16), (10, 24)]


def test_refractory_time_blocks_a_quick_second_touch():
    trig = ThresholdTrigger(4, fullscale=1000, fraction=0.15, hysteresis=0.05, refractory_frames=5, window=15)
    levels = [200, 0, 200, 0, 0, 200, 0]
    assert _run(trig, levels) == [(0, 14), (5, 19)]


def test_pre_frames_shift_the_window_end():
    trig = ThresholdTrigger(2, fullscale=1000, fraction=0.15, window=15, pre_frames=3)
    assert _run(trig, [0, 0, 0, 0, 500], 2) == [(4, 15)]


def test_baseline_mode_ignores_the_grasp_pressure():
    fs = 4095
    trig = ThresholdTrigger(2, fullscale=fs, fraction=0.15, hysteresis=0.05, refractory_frames=0, window=15,
                            baseline=True, baseline_alpha=0.2)
    plain = ThresholdTrigger(2, fullscale=fs, fraction=0.15, hysteresis=0.05, refractory_frames=0, window=15)
    row = np.zeros(2, dtype=np.float32)
    fired, fired_plain = [], []
    for i in range(60):
        row[0] = 1500.0  # the grasp presses one taxel hard all the time
        row[1] = 1500.0 + (800.0 if 40 <= i < 45 else 0.0)  # the person adds 800 for a moment
        if trig.update(row, i) >= 0:
            fired.append(i)
        if plain.update(row, i) >= 0:
            fired_plain.append(i)
    assert fired_plain == [0]  # the absolute threshold only sees the grasp
    assert fired == [40]


def test_continuous_trigger_ends_a_window_every_frame():
    trig = ContinuousTrigger(15)
    assert [trig.update(np.zeros(2, np.float32), i) for i in range(3)] == [0, 1, 2]


# A push as the simulated hand makes it (synthetic): over the level, its pressure wobbles and
# dips below the re-arm level for 4 frames mid-interaction, rises again, then the person lets go.
WOBBLING_PUSH = [0, 0, 200, 220, 180, 90, 80, 85, 95, 170, 210, 190, 160, 120, 60, 0] + [0] * 12 + [200, 0]


def test_a_wobbling_push_is_one_trigger_once_rearming_needs_quiet_frames():
    def fired(rearm_frames: int) -> list[int]:
        trig = ThresholdTrigger(4, fullscale=1000, fraction=0.15, hysteresis=0.05, refractory_frames=0, window=15,
                                rearm_frames=rearm_frames)
        return [i for i, _ in _run(trig, WOBBLING_PUSH)]

    assert fired(1) == [2, 9, 28]  # the old rule: the dip re-arms, one push is reported twice
    assert fired(8) == [2, 28]  # quiet for 8 frames (0.25 s at 32 Hz) before re-arming: one per push
    assert fired(20) == [2]  # a re-arm time longer than the pause between touches merges them


def test_rearm_frames_must_be_positive():
    with pytest.raises(ValueError, match="rearm_frames"):
        ThresholdTrigger(4, fullscale=1000, rearm_frames=0)


def test_the_model_hysteresis_is_served_unless_the_config_sets_one(tmp_path):
    """Training records ``trigger.hysteresis`` in the model; the daemon re-arms at that level when
    its config sets none (config value, else the model's, else the default, capped below the level)."""
    pytest.importorskip("onnx")
    from runtime.config import config_from_dict
    from runtime.detector import Detector
    from runtime.model import load_model
    from runtime.trigger_settings import DEFAULT_HYSTERESIS, HYSTERESIS_CAP, PAPER_FRACTION
    from tests.tiny_models import tiny_model_bytes, write_model

    layout = SensorLayout.sdh2()
    fullscale = 4095.0

    def off_level(model_trigger: dict, config_trigger: dict) -> float:
        name = f"m{len(list(tmp_path.iterdir()))}.onnx"
        path = write_model(tmp_path, name, tiny_model_bytes(trigger={"kind": "threshold", **model_trigger}))
        detector = Detector(trigger=config_from_dict({"trigger": config_trigger}).trigger)
        detector.swap(load_model(path), layout)
        assert isinstance(detector.trigger, ThresholdTrigger)
        return detector.trigger.off_level

    assert off_level({"hysteresis": 0.02}, {}) == pytest.approx((PAPER_FRACTION - 0.02) * fullscale)
    assert off_level({"hysteresis": 0.02}, {"hysteresis": 0.1}) == pytest.approx((PAPER_FRACTION - 0.1) * fullscale)
    assert off_level({}, {}) == pytest.approx((PAPER_FRACTION - DEFAULT_HYSTERESIS) * fullscale)
    low = 0.03  # the default hysteresis would re-arm below zero: capped
    assert off_level({"fraction": low}, {}) == pytest.approx(low * (1 - HYSTERESIS_CAP) * fullscale, rel=1e-4)


def test_a_model_with_a_broken_hysteresis_is_refused(tmp_path):
    pytest.importorskip("onnx")
    from runtime.model import ModelContractError, load_model
    from tests.tiny_models import tiny_model_bytes, write_model

    path = write_model(tmp_path, "bad.onnx", tiny_model_bytes(trigger={"kind": "threshold", "hysteresis": 2.0}))
    with pytest.raises(ModelContractError, match=r"trigger\.hysteresis"):
        load_model(path)
