"""The onset trigger, its settings, the robot's grasp messages and the control socket (small synthetic streams)."""

from __future__ import annotations

import contextlib
import functools
import logging
import time
from collections.abc import Iterator

import numpy as np
import pytest

from firmware_io.client import Frame
from firmware_io.layout import SensorLayout
from runtime.config import ConfigError, TriggerConfig, config_from_dict
from runtime.control import parse_message
from runtime.daemon import Daemon
from runtime.detector import Detector
from runtime.onset import ARMED, COMPRESSION_CAP, OPEN, RUBBER_HILL_N, OnsetTrigger, compression
from runtime.trigger_settings import DEFAULT_KIND, PAPER_FRACTION, build_trigger, recorded_problems, resolve_trigger
from tests.datagrams import send_datagram
from tests.waiting import wait_for

LAYOUT = SensorLayout.sdh2()
PADS = (78, 78, 78)
RATE = 32.0
CONTACT = [np.arange(p * 78 + 20, p * 78 + 40) for p in range(3)]  # 20 loaded taxels per distal pad


def _trigger() -> OnsetTrigger:
    return build_trigger(resolve_trigger(TriggerConfig(kind="onset")), PADS, 4095.0, 15, RATE)


def grasp_levels(n: int, close: int = 20, level: float = 1500.0, creep: float = 0.10, seed: int = 0) -> np.ndarray:
    """Per frame and pad the loaded taxels' value: a 0.3 s close, the rubber creeping +10 % (tau 4 s), 1 % noise."""
    t = np.arange(n, dtype=float)
    ramp = np.clip((t - close) / 10.0, 0.0, 1.0)
    ramp = ramp * ramp * (3 - 2 * ramp)
    age = np.clip(t - close, 0.0, None) / RATE
    v = level * ramp * (1.0 + creep * (1.0 - np.exp(-age / 4.0)))
    noise = 1.0 + 0.01 * np.random.default_rng(seed).standard_normal((n, 3))
    return v[:, None] * noise


def rows_of(levels: np.ndarray) -> np.ndarray:
    rows = np.zeros((len(levels), sum(PADS)), dtype=np.float32)
    for p in range(3):
        rows[:, CONTACT[p]] = levels[:, p:p + 1]
    return rows


def fires(trig, rows: np.ndarray) -> list[int]:
    return [i for i in range(len(rows)) if trig.update(rows[i], i) >= 0]


def test_onset_fires_when_the_person_acts_not_at_the_close_nor_on_creep():
    levels = grasp_levels(400)
    push = np.clip((np.arange(400) - 200) / 5.0, 0, 1) * np.exp(-np.clip(np.arange(400) - 230, 0, None) / 10.0)
    levels[:, 0] *= 1.0 + 0.3 * push  # a push on pad 0 from frame 200
    trig = _trigger()
    assert len(out := fires(trig, rows_of(levels))) == 1 and 200 <= out[0] <= 203  # not at the close (20), not on creep


def _pressed(n: int, start: int, rise: float, top: float = 0.3) -> np.ndarray:
    """A clean held grasp whose pad 0 gains ``rise`` of its level per frame from ``start`` (up to ``top``)."""
    levels = grasp_levels(n, creep=0.0)
    levels[:, 0] *= 1.0 + np.clip((np.arange(n) - start) * rise, 0.0, top)
    return levels


def test_a_slow_departure_dates_its_window_from_where_it_began_and_a_fast_one_from_its_frame():
    """A hold rising 2 % a frame crosses 12 % six frames in, 6 % three frames in: its window starts there
    (at most ``back_frames`` back); a step crosses both at once and is not dated back."""
    for rise, back in ((0.02, 3), (0.5, 0)):
        trig = _trigger()
        rows = rows_of(_pressed(200, 150, rise))
        due = [(i, d) for i in range(200) if (d := trig.update(rows[i], i)) >= 0]
        assert len(due) == 1 and trig.back == back
        fired, end = due[0]
        assert end - 15 + 1 == fired - back
    capped = build_trigger(resolve_trigger(TriggerConfig(kind="onset")), PADS, 4095.0, 15, RATE)
    capped.back_frames = 1
    rows = rows_of(_pressed(200, 150, 0.015))  # dated back further without the cap
    assert fires(capped, rows) and capped.back == 1


def test_a_model_that_records_no_back_frames_is_served_as_it_was_cut():
    assert resolve_trigger(None, {"kind": "onset", "change": 0.12}).back_frames == 0
    assert resolve_trigger(None, {"kind": "onset", "back_frames": None}).back_frames == 0
    assert recorded_problems({"kind": "onset", "back_frames": 3.5}) == ["trigger.back_frames 3.5 must be a whole number in [0, 1000]"]
    assert resolve_trigger().back_frames == 3 and resolve_trigger(None, {"kind": "onset", "back_frames": 2}).back_frames == 2
    with pytest.raises(ValueError, match="back_frames"):
        OnsetTrigger(PADS, 4095.0, 0.12, 0.25, 0.02, 32.0, 6, 0.02, window=15, pre_frames=10, back_frames=5)


def test_the_hand_letting_go_is_not_an_event():
    levels = grasp_levels(300)
    levels[200:] *= np.clip(1.0 - (np.arange(100) / 10.0), 0, 1)[:, None]  # the hand opens at 200
    trig = _trigger()
    assert fires(trig, rows_of(levels)) == [] and trig.releases == 1 and trig.state == OPEN


def test_a_pad_letting_go_while_another_wobbles_up_a_little_is_not_an_event():
    levels = grasp_levels(300)
    levels[200:, 0] *= 0.8  # pad 0 loses 20 % (the hand starts to open) ...
    levels[200:, 1] *= 1.05  # ... while pad 1 wobbles up 5 %: no pad rose by the change
    trig = _trigger()
    assert fires(trig, rows_of(levels)) == [] and trig.releases == 1


@pytest.mark.parametrize("taxels, fired", [(2, False), (3, True), (20, True)])
def test_a_point_contact_rolling_on_a_pad_is_not_an_event(taxels, fired):
    levels = grasp_levels(300, level=1500.0 * 20 / taxels)  # the same pad force on fewer taxels
    levels[200:, 0] *= 1.5  # the load on pad 0 jumps by half
    rows = rows_of(levels)
    for p in range(3):
        rows[:, CONTACT[p][taxels:]] = 0.0  # only ``taxels`` of each pad's contact are loaded
    trig = _trigger()
    assert bool(fires(trig, rows)) == fired and trig.point_contacts == (not fired)


def test_one_trigger_per_interaction_while_the_pressure_wobbles():
    levels = grasp_levels(500)
    t = np.arange(500)
    wobble = np.where((t >= 150) & (t < 190), 0.25 * np.abs(np.sin((t - 150) / 3.0)), 0.0)  # 1.2 s of push and dips
    levels[:, 1] *= 1.0 + wobble
    trig = _trigger()
    assert len(out := fires(trig, rows_of(levels))) == 1 and 150 <= out[0] <= 153
    assert trig.state == ARMED  # settled again after the interaction: ready for the next one


@pytest.mark.parametrize("jitter, armed", [(0.015, True), (0.025, False)])
def test_a_held_grasp_jittering_on_noise_settles_but_one_moving_more_does_not(jitter, armed):
    levels = np.full((200, 3), 1500.0)
    levels[:20] = 0.0  # an empty hand, then a grasp whose every pad swings +-jitter from frame to frame
    levels[20:] *= 1.0 + jitter * (-1.0) ** np.arange(180)[:, None]  # 3 % per frame: over the strict 2 %
    trig = _trigger()
    states = [(trig.update(row, i), trig.state)[1] for i, row in enumerate(rows_of(levels))]
    settle_frames = round(resolve_trigger(TriggerConfig(kind="onset")).settle_s * RATE)
    assert (ARMED in states) == armed
    assert not armed or states.index(ARMED) == 20 + 3 * settle_frames  # three times the strict test's time


@pytest.mark.parametrize("rate", [0.025, 0.03, 0.039])
def test_a_hand_squeezing_steadily_under_the_noisy_bound_does_not_fire_on_its_own_grasp(rate):
    t = np.arange(300)
    levels = 600.0 * (1.0 + rate) ** np.clip(t - 20, 0, 60)[:, None] * np.ones((1, 3))  # 60 frames of squeeze, then held
    levels[:20] = 0.0  # every pad moves under 2 x settle_change per frame, but always the same way: not noise
    trig = _trigger()
    states = [(trig.update(row, i), trig.state)[1] for i, row in enumerate(rows_of(levels))]
    assert ARMED in states and states.index(ARMED) > 80  # armed on the held grasp, not mid-squeeze (nothing fired)


def test_a_noisy_hand_squeezing_slowly_or_squeezing_after_a_push_does_not_fire_on_its_own_grasp():
    """Two streams of an attacker: a noisy grasp tightening 1.25 % per frame (it passed the per-frame tests
    and armed mid-squeeze, firing 3 times in 6 s), and a push followed by the hand squeezing 3 % per frame
    (the span's bound grew while the refractory time kept the trigger settling, and it fired again)."""
    t = np.arange(260, dtype=float)
    close = np.clip((t - 20) / 10, 0, 1)
    close = close * close * (3 - 2 * close)
    noise = 1 + np.random.default_rng(0).uniform(-0.015, 0.015, (260, 3))
    slow = np.repeat((400 * close * 1.0125 ** np.clip(t - 30, 0, None))[:, None], 3, 1) * noise
    assert fires(_trigger(), rows_of(slow[:200])) == []
    pushed = np.repeat((400 * close)[:, None], 3, 1)
    pushed[100:] *= 1.3  # a person pushes at 100 ...
    pushed *= (1.03 ** np.clip(t - 130, 0, 30))[:, None]  # ... then the hand alone squeezes 3 % per frame
    assert fires(_trigger(), rows_of(pushed)) == [100]


def test_robot_grasp_closed_arms_at_once_and_open_disarms():
    levels = grasp_levels(200, close=20)
    levels[40:, 2] *= 1.0 + 0.3 * np.clip((np.arange(160)) / 5.0, 0, 1)[:, None].ravel()  # acts as the close ends
    rows = rows_of(levels)
    alone = _trigger()
    assert fires(alone, rows) == []  # never saw a settled grasp before the person acted
    told = _trigger()
    out = []
    for i in range(len(rows)):
        if i == 32:
            told.set_grasp(True)  # the robot: my grasp has settled
        if told.update(rows[i], i) >= 0:
            out.append(i)
    assert len(out) == 1 and 40 <= out[0] <= 43
    opened = _trigger()
    still = rows_of(grasp_levels(200, creep=0.0))
    for i in range(100):
        opened.update(still[i], i)
    assert opened.state == ARMED
    opened.set_grasp(False)
    bump = still[100:].copy()
    bump[10:15, CONTACT[0]] *= 1.5
    assert [i for i in range(100) if opened.update(bump[i], 100 + i) >= 0] == []  # no events after "grasp open"
    assert opened.robot_open and opened.state == OPEN


def test_settings_come_from_config_then_model_then_default():
    assert resolve_trigger().kind == DEFAULT_KIND
    old_model = resolve_trigger(None, {"fraction": 0.2})  # cut before the onset trigger existed
    assert old_model.kind == "threshold" and old_model.fraction == 0.2
    onset_model = resolve_trigger(None, {"kind": "onset", "fraction": PAPER_FRACTION, "change": 0.05})
    assert onset_model.kind == "onset" and onset_model.change == 0.05
    cfg = TriggerConfig(kind="threshold", fraction=0.3)
    assert resolve_trigger(cfg, {"kind": "onset", "fraction": 0.1}).fraction == 0.3
    assert resolve_trigger(TriggerConfig(change=0.12), {"kind": "onset", "change": 0.05}).change == 0.12


@pytest.mark.parametrize(("table", "message"), [
    ({"trigger": {"kind": "level"}}, "trigger.kind"),
    ({"trigger": {"change": 1.5}}, "trigger.change"),
    ({"control": {"socket": "relative.sock"}}, "control.socket"),
    ({"control": {"port": 1}}, "control.port"),
])
def test_bad_trigger_and_control_keys_are_one_line(table, message):
    with pytest.raises(ConfigError, match=message):
        config_from_dict(table)


def test_control_messages():
    assert parse_message(b"grasp closed\n") == ("grasp", True) and parse_message(b"  GRASP   open ") == ("grasp", False)
    assert parse_message(b"arm moving") == ("arm", True) and parse_message(b"ARM  still\n") == ("arm", False)
    assert parse_message(b"grasp") is None and parse_message(b"\xff\xfe") is None and parse_message(b"arm") is None


# -- the daemon --------------------------------------------------------------------------------------
def _onset_model(tmp_path):
    from runtime.model import load_model
    from tests.tiny_models import tiny_model_bytes, write_model

    data = tiny_model_bytes(weights=(1.0, 0.0, 0.0, 0.0), bias=(0.0, 0.1, 0.0, 0.0), trigger={"kind": "onset"})
    return load_model(write_model(tmp_path, "onset.onnx", data))


def _frames(levels: np.ndarray) -> list[Frame]:
    rows = rows_of(levels)
    full = np.zeros((len(rows), LAYOUT.n_taxels), dtype=np.uint16)
    full[:, LAYOUT.columns("distal")] = rows.astype(np.uint16)
    return [Frame(i, int(i * 1000 / RATE), time.perf_counter(), full[i]) for i in range(len(full))]


def _daemon(tmp_path, **tables) -> tuple[Daemon, list]:
    cfg = config_from_dict({"sinks": {"stdout": False}, "log_level": "warning", **tables})
    events: list = []
    daemon = Daemon(cfg, on_event=events.append)
    daemon.serve(_onset_model(tmp_path), LAYOUT)
    return daemon, events


def test_daemon_serves_a_model_cut_by_the_onset_trigger_with_it(tmp_path):
    daemon, events = _daemon(tmp_path)
    assert isinstance(daemon.detector.trigger, OnsetTrigger) and daemon.detector.trigger_settings.kind == "onset"
    levels = grasp_levels(400)
    levels[200:240, 0] *= 1.3
    for frame in _frames(levels):
        daemon.handle_frame(frame)
    assert len(events) == 1 and 200 <= events[0].frame_first <= 202  # from the person's onset (200), not the close (20)


_wait = functools.partial(wait_for, timeout=3.0)


@contextlib.contextmanager
def _listening(tmp_path) -> Iterator[tuple[Daemon, str]]:
    """A daemon with its control socket open (and the socket's path), stopped on the way out."""
    path = str(tmp_path / "control.sock")
    daemon, _ = _daemon(tmp_path, control={"socket": path})
    daemon.start_control()
    try:
        yield daemon, path
    finally:
        daemon.stop_control()


def test_control_datagram_arms_the_trigger_and_garbage_is_counted_and_logged_once(tmp_path, caplog):
    with _listening(tmp_path) as (daemon, path):
        frames = _frames(grasp_levels(60, close=0))
        daemon.handle_frame(frames[0])
        send_datagram(path, b"grasp closed\n")
        assert _wait(lambda: daemon.control.received == 1)
        daemon.handle_frame(frames[1])
        assert daemon.detector.grasp_closed is True and daemon.detector.trigger.state == ARMED
        with caplog.at_level(logging.WARNING, logger="handover.control"):
            send_datagram(path, b"\xff\xfe\x00")
            send_datagram(path, b"grasp sideways")
            assert _wait(lambda: daemon.control.garbage == 2)
        assert sum("ignored a datagram" in r.getMessage() for r in caplog.records) == 1
        send_datagram(path, b"GRASP OPEN")
        assert _wait(lambda: daemon.control.received == 2)
        daemon.handle_frame(frames[2])
        assert daemon.detector.grasp_closed is False and daemon.detector.trigger.state == OPEN and daemon.detector.trigger.robot_open
        daemon.robot.set_grasp(True, source="ros2")  # what the ROS 2 sink calls
        daemon.handle_frame(frames[3])
        assert daemon.detector.trigger.state == ARMED
    assert not (tmp_path / "control.sock").exists()


def test_a_control_socket_that_cannot_bind_stops_the_daemon_in_one_line(tmp_path):
    """A daemon deaf to the robot's ``grasp open`` must not run as if all were well (handover run exits 2)."""
    daemon, _ = _daemon(tmp_path, control={"socket": str(tmp_path / "missing" / "c.sock")})
    with pytest.raises(OSError, match="cannot bind") as info:
        daemon.start_control()
    assert daemon.control is None and "\n" not in str(info.value)


# -- continuous mode: a hold is a change of level, which the level features see -----------------------
def _windows(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    X = np.zeros((n, sum(PADS), 15), dtype=np.float32)
    t = np.arange(15) / 14.0
    for i in range(n):
        level = rng.uniform(800, 1500)
        shape = {"dormant": np.ones(15), "hold": 1.0 + rng.uniform(0.1, 0.25) * t,
                 "bump": 1.0 + 0.5 * np.exp(-0.5 * ((np.arange(15) - rng.uniform(4, 10)) / 1.0) ** 2)}[kind]
        for p in range(3):
            X[i, CONTACT[p], :] = level * shape * (1 + 0.01 * rng.standard_normal((20, 15)))
    return X


def test_continuous_mode_reports_a_hold_once(tmp_path):
    from runtime.model import load_model
    from trainer import dormant
    from trainer.classifier import BowSVC

    rng = np.random.default_rng(0)
    kinds = ("dormant", "hold", "bump")
    X = np.concatenate([_windows(k, 40, rng) for k in kinds])
    y = np.repeat(kinds, 40)
    model = BowSVC(n_words=4, window=3, kernel="rbf", C=10.0, gamma=0.05, per_pad=True, pad_sizes=PADS,
                   level_features=True, scale_features=True).fit(X, y)
    path = dormant.export(model, tmp_path / "five.onnx", pads=(1, 3, 5), pad_sizes=PADS, fullscale=4095.0,
                          fraction=PAPER_FRACTION, sample_rate_hz=RATE, dormant_class="dormant",
                          training={"data_fingerprint": "test", "n_trials": 0})
    cfg = config_from_dict({"scene": {"mode": "continuous", "events": ["hold", "bump"]}, "continuous": {"confirm_frames": 4}})
    detector = Detector(cfg.scene, cfg.trigger, cfg.continuous)
    detector.swap(load_model(path), LAYOUT)
    levels = np.full((260, 3), 1200.0)
    levels[100:125] *= (1.0 + 0.2 * np.arange(25) / 24.0)[:, None]  # a person grips: +20 % over 0.8 s
    levels[125:] *= 1.2  # ... and holds
    reported = [d for d in map(detector.feed, _frames(levels)) if d is not None and d.cls is not None]
    assert [d.cls for d in reported] == ["hold"] and 100 <= reported[0].frame.number <= 125


def test_a_reload_that_changes_no_trigger_setting_keeps_the_settled_grasp(tmp_path):
    """SIGHUP rebuilt the onset trigger, which then had to find the settled grasp again (the attacker:
    a storm of reloads gave 0 decisions in 18 s). Same settings: the same trigger, its state kept."""
    daemon, events = _daemon(tmp_path)
    levels = grasp_levels(400)
    levels[200:240, 0] *= 1.3
    frames = _frames(levels)
    for frame in frames[:150]:  # the grasp has settled
        daemon.handle_frame(frame)
    trigger = daemon.detector.trigger
    daemon.detector.rebuild(keep_history=True)  # what a reload with an unchanged scene and trigger does
    assert daemon.detector.trigger is trigger
    for frame in frames[150:]:
        daemon.handle_frame(frame)
    assert len(events) == 1 and 200 <= events[0].frame_first <= 202
    daemon.detector.rebuild(keep_history=False)  # a reconnect forgets the history: a new trigger
    assert daemon.detector.trigger is not trigger


@pytest.mark.parametrize("level, fired", [(500.0, False), (2700.0, True)])
def test_a_hold_on_a_grasp_that_compresses_the_rubber_is_read_as_force(level, fired):
    """7 % more counts is ~25 % more force where the grasp sits high on the rubber's curve (a firm grasp
    on a sensitive pad), but only ~5 % on a light grasp, which stays below the change as before."""
    levels = grasp_levels(300, level=level)
    levels[200:, 0] *= 1.07  # a person holds: pad 0's readings rise by 7 %
    trig = _trigger()
    assert bool(fires(trig, rows_of(levels))) == fired


def test_the_compression_factor_leaves_a_light_grasp_alone_and_is_capped():
    starts = np.array([0, 78, 156])
    row = np.zeros(234, dtype=np.float32)
    row[20:40], row[98:118], row[176:196] = 500.0, 2000.0, 4095.0
    g = compression(row, starts, 4095.0)
    assert g[0] == 1.0 and 1.0 < g[1] < g[2] <= 1.0 / (RUBBER_HILL_N * (1.0 - COMPRESSION_CAP)) + 1e-9
