"""The daemon feeds a model at its trained period (runtime/frame_rate.py), on small synthetic streams."""

from __future__ import annotations

import copy
import dataclasses
import logging
import time

import numpy as np
import pytest

from firmware_io.client import Frame
from firmware_io.wire.device_time import TimestampUnwrapper
from runtime.frame_rate import BLOCK, FrameClock
from runtime.health import Health
from tests.test_onset import LAYOUT, RATE, _daemon, grasp_levels, rows_of

MODEL_MS = 1000.0 / RATE


def stamps(rate_hz: float, n: int, jitter_ms: float = 0.0, seed: int = 0) -> np.ndarray:
    """Device time stamps (ms) of a stream at ``rate_hz``, each jittered by up to ``jitter_ms``."""
    t = np.arange(n) * 1000.0 / rate_hz
    t += np.random.default_rng(seed).uniform(-jitter_ms, jitter_ms, n)
    return np.rint(t).astype(np.int64)


def admit_all(clock: FrameClock, ts: np.ndarray) -> list[int]:
    return [clock.admit(i, int(t)) for i, t in enumerate(ts)]


def test_a_stream_at_the_model_rate_passes_untouched_despite_jitter():
    health = Health()
    clock = FrameClock(MODEL_MS, health)
    numbers = admit_all(clock, stamps(RATE, 400, jitter_ms=0.4 * MODEL_MS))
    assert numbers == list(range(400)) and not clock.renumber
    assert clock.dropped == 0 and clock.decimated == 0 and health.last_error == ""


def test_a_70hz_stream_is_decimated_to_the_model_period():
    health = Health()
    clock = FrameClock(MODEL_MS, health)
    ts = stamps(70.0, 2000, jitter_ms=4.0)
    numbers = admit_all(clock, ts)
    admitted = [i for i, n in enumerate(numbers) if n >= 0]
    later = [i for i in admitted if i > BLOCK]  # the rate is known after the first block
    spacing_ms = np.diff(ts[later]).mean()
    assert spacing_ms == pytest.approx(MODEL_MS, rel=0.03)
    kept = [n for n in numbers if n >= 0]
    assert kept == list(range(len(kept)))  # consecutive model frames for the trigger
    assert clock.decimated == 2000 - len(kept) and clock.dropped == 0
    first = clock.window_first(admitted[-1], 15)  # a window of 15 model frames spans 0.44 s of device time
    assert (ts[admitted[-1]] - ts[first]) == pytest.approx(14 * MODEL_MS, rel=0.1)


def test_lost_frames_count_against_the_stream_period():
    health = Health()
    clock = FrameClock(MODEL_MS, health)
    ts = np.delete(stamps(70.0, 400), [100, 101, 102, 250])  # 4 frames lost in a 70 Hz stream
    admit_all(clock, ts)
    assert clock.dropped == 4


def test_a_slower_stream_is_one_health_line_and_resolves(caplog):
    health = Health()
    clock = FrameClock(MODEL_MS, health)
    with caplog.at_level(logging.WARNING, logger="handover.daemon"):
        admit_all(clock, stamps(16.0, 200))
    lines = [r.getMessage() for r in caplog.records if "slower" in r.getMessage()]
    assert len(lines) == 1 and "16 Hz" in lines[0] and "than the 32 Hz" in lines[0]
    assert health.last_error == lines[0] and clock.dropped == 0  # 16 Hz gaps are not lost frames
    last = 200 * 1000 // 16
    for i in range(200, 300):  # back at the model's rate
        clock.admit(i, int(last + (i - 199) * MODEL_MS))
    assert health.last_error == ""


def test_a_long_gap_restarts_the_stream():
    restarts: list[int] = []
    clock = FrameClock(MODEL_MS, Health(), on_restart=lambda: restarts.append(1))
    ts = stamps(RATE, 200)
    ts[120:] += 3000  # the recording paused for 3 s
    admit_all(clock, ts)
    assert len(restarts) == 1


def _resampled(levels: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The same motion (levels per pad at 32 Hz) sampled at ``rate_hz``: rows and stamps (ms)."""
    t32 = np.arange(len(levels)) / RATE
    t = np.arange(0.0, t32[-1], 1.0 / rate_hz)
    out = np.stack([np.interp(t, t32, levels[:, p]) for p in range(levels.shape[1])], axis=1)
    return out, np.rint(t * 1000.0).astype(np.int64)


def _events(tmp_path, levels: np.ndarray, ts: np.ndarray) -> list:
    daemon, events = _daemon(tmp_path)
    rows = rows_of(levels)
    full = np.zeros((len(rows), LAYOUT.n_taxels), dtype=np.uint16)
    full[:, LAYOUT.columns("distal")] = rows.astype(np.uint16)
    for i in range(len(full)):
        daemon.handle_frame(Frame(i, int(ts[i]), time.perf_counter(), full[i]))
    return events


def test_a_70hz_stream_gives_the_decisions_of_the_same_motion_at_32hz(tmp_path):
    levels = grasp_levels(400, seed=3)
    levels[200:240, 0] *= 1.3  # a person presses on pad 0 at 6.25 s
    slow = _events(tmp_path, levels, np.rint(np.arange(400) * MODEL_MS).astype(np.int64))
    fast_levels, fast_ts = _resampled(levels, 70.0)
    fast = _events(tmp_path, fast_levels, fast_ts)
    assert [e.cls for e in fast] == [e.cls for e in slow] and len(slow) == 1
    t_first = {name: ts[e.frame_first] for name, ts, e in
               (("slow", np.arange(400) * MODEL_MS, slow[0]), ("fast", fast_ts, fast[0]))}
    assert abs(t_first["fast"] - t_first["slow"]) <= 2 * MODEL_MS  # the same onset, within 2 model frames
    span_ms = fast_ts[fast[0].frame_last] - fast_ts[fast[0].frame_first]
    assert span_ms == pytest.approx(14 * MODEL_MS, rel=0.1)  # the trained 0.44 s, not 14 / 70 Hz = 0.2 s


def test_a_jump_across_a_pause_in_the_recording_is_not_an_event(tmp_path):
    levels = grasp_levels(400, seed=4)
    levels[200:, :] *= 1.3  # the grasp is 30 % firmer after the pause ...
    ts = np.rint(np.arange(400) * MODEL_MS).astype(np.int64)
    assert len(_events(tmp_path, levels, ts)) == 1  # ... which, without a pause, is a person pressing
    ts[200:] += 3000  # the recording paused for 3 s before frame 200
    assert _events(tmp_path, levels, ts) == []


def test_stamps_of_a_broken_device_clock_are_not_believed():
    health = Health()
    clock = FrameClock(MODEL_MS, health)
    numbers = admit_all(clock, np.arange(200))  # 1 ms per frame: 1000 Hz
    assert numbers == list(range(200)) and "one of them is wrong" in health.last_error


def test_the_deadline_is_the_streams_measured_period_not_the_models_claim():
    """A model claiming 1 Hz on a 32 Hz stream: decisions have until the next frame, 31.25 ms, not 1 s."""
    clock = FrameClock(1000.0, Health())
    assert clock.deadline_s() == 1.0  # nothing measured yet: the model's period
    admit_all(clock, np.rint(np.arange(100) * 31.25).astype(np.int64))
    assert abs(clock.deadline_s() - 0.03125) < 1e-3
    decimated = FrameClock(MODEL_MS, Health())  # a 70 Hz stream fed to a 32 Hz model: the next admitted frame
    admit_all(decimated, np.rint(np.arange(200) * 1000 / 70).astype(np.int64))
    assert abs(decimated.deadline_s() - MODEL_MS / 1000) < 1e-3


def test_a_device_reboot_mid_stream_restarts_the_history_and_is_not_an_event(tmp_path):
    """The controller reboots: its counter restarts at 0, which the client's unwrapper reads as
    device time going back. A window across it would join two unrelated moments."""
    levels = grasp_levels(400, seed=4)
    levels[200:, :] *= 1.3
    ts = np.rint(np.arange(400) * MODEL_MS).astype(np.int64) + 600_000  # 10 min of uptime
    unwrap = TimestampUnwrapper()
    ts[200:] -= ts[200]  # the counter restarts at 0 before frame 200
    assert _events(tmp_path, levels, np.array([unwrap(int(t)) for t in ts])) == []


def test_breaks_in_device_time_are_neither_lost_frames_nor_rate_estimates(caplog):
    """A stamp an hour ahead (and back), a step back by a second: restarts, one log line, no loss."""
    health, restarts = Health(), []
    clock = FrameClock(MODEL_MS, health, on_restart=lambda: restarts.append(1))
    ts = stamps(RATE, 400)
    ts[100] += 3_600_000
    ts[300:] -= 1000
    with caplog.at_level(logging.WARNING, logger="handover.daemon"):
        assert admit_all(clock, ts) == list(range(400))
    assert len(restarts) == 3 and clock.dropped == 0 and clock.stream_period_ms == pytest.approx(MODEL_MS)
    assert len(caplog.records) == 1 and "device time jumped 3600.0 s ahead" in caplog.records[0].getMessage()


@pytest.mark.parametrize("gaps", [[10, 50], [10, 50, 10, 50, 10]], ids=["even", "odd"])
def test_alternating_jitter_is_read_as_its_mean_period(gaps):
    """Gaps alternating 10 / 50 ms are a 33-38 Hz stream, not 100 Hz one to decimate with frames lost."""
    health = Health()
    clock = FrameClock(MODEL_MS, health)
    ts = np.cumsum(np.tile(gaps, 400 // len(gaps)))
    assert admit_all(clock, ts) == list(range(len(ts)))
    assert clock.dropped == 0 and clock.decimated == 0 and health.last_error == ""


def test_repeated_stamps_lose_no_frames():
    clock = FrameClock(MODEL_MS, Health())
    admit_all(clock, np.repeat(stamps(RATE, 200), 2))
    assert clock.dropped == 0


def test_a_stream_flapping_between_rates_logs_each_kind_once(caplog):
    health = Health()
    clock = FrameClock(MODEL_MS, health)
    ts, t = [], 0.0
    for k in range(20):  # 2 s at 70 Hz, 2 s at 32 Hz, 2 s at 16 Hz, ...
        for _ in range(128):
            t += 1000.0 / (70.0, RATE, 16.0)[k % 3]
            ts.append(round(t))
    with caplog.at_level(logging.WARNING, logger="handover.daemon"):
        admit_all(clock, np.array(ts))
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and "decimated" in lines[0] and "slower" in lines[1]


def test_a_swap_to_a_model_at_another_rate_forgets_frames_admitted_at_the_old_one(tmp_path):
    """A 70 Hz stream decimated for a 32 Hz model; a 70 Hz model swaps in: the ring's frames are
    0.03 s apart, the new model's windows need 0.014 s, so they are not mixed into its windows."""
    daemon, _ = _daemon(tmp_path)
    fast_levels, fast_ts = _resampled(grasp_levels(200, seed=5), 70.0)
    rows = rows_of(fast_levels)
    full = np.zeros((len(rows), LAYOUT.n_taxels), dtype=np.uint16)
    full[:, LAYOUT.columns("distal")] = rows.astype(np.uint16)
    for i in range(200):
        daemon.handle_frame(Frame(i, int(fast_ts[i]), time.perf_counter(), full[i]))
    assert daemon.detector.ring.count > 15 and daemon.detector.frame_clock.step < 1.0
    model = daemon.model
    same = copy.copy(model)
    daemon.models.use(same)  # the same rate: the history stays
    assert daemon.detector.ring.count > 15
    other = copy.copy(model)
    other.meta = dataclasses.replace(model.meta, sample_rate_hz=70.0)
    daemon.models.use(other)
    assert daemon.detector.ring.count == 0 and daemon.detector.frame_clock.step == 1.0
    for i in range(200, 230):
        daemon.handle_frame(Frame(i, int(fast_ts[i]), time.perf_counter(), full[i]))
    assert daemon.detector.ring.count == 30  # every frame of the 70 Hz stream, from the swap on


@pytest.mark.parametrize(("model_hz", "device_hz"), [(32.0, 2.0), (1000.0, 32.0)])
def test_a_stream_far_slower_than_the_model_is_measured_and_warned_about(model_hz, device_hz):
    """Every gap is a break by the model's period until the stream's own is known: measured
    from the first block, then one health line, and no more breaks."""
    health, restarts = Health(), []
    clock = FrameClock(1000.0 / model_hz, health, on_restart=lambda: restarts.append(1))
    admit_all(clock, stamps(device_hz, 200))
    assert clock.stream_period_ms == pytest.approx(1000.0 / device_hz, rel=0.01)
    assert len(restarts) <= BLOCK and "slower" in health.last_error and clock.dropped == 0

