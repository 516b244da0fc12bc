"""The detector (runtime.detector): frames in, decisions out, with nothing of the service around it;
and the daemon built around one detector (windows held back for a swap, a model taken out of service)."""

from __future__ import annotations

import functools
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from firmware_io.client import Frame
from firmware_io.layout import SensorLayout
from firmware_io.recordings.recording import Recording
from runtime.config import ContinuousConfig, SceneConfig, TriggerConfig, config_from_dict
from runtime.daemon import Daemon
from runtime.decision import ContinuousDecision
from runtime.detector import Detector, ReportRule, Run, Windows
from runtime.early import EarlyRule, EarlySpec
from runtime.model import load_model
from runtime.sinks import Event
from tests.tiny_models import tiny_model_bytes, write_model
from tests.waiting import wait_for

LAYOUT = SensorLayout.sdh2()


def _pushes() -> Recording:
    """Two pushes on one distal taxel, 32 Hz: frames for about 3 s."""
    column = int(LAYOUT.columns("distal")[40])
    levels = [0] * 5 + [900] * 20 + [0] * 45 + [900] * 20
    frames = np.zeros((len(levels), LAYOUT.n_taxels), dtype=np.uint16)
    frames[:, column] = levels
    return Recording(LAYOUT, frames, np.arange(len(levels)) / 32.0)


def _frames(rec: Recording, first: int = 0):
    for i, values in enumerate(rec.frames):
        yield Frame(first + i, round((first + i) * 31.25), time.perf_counter(), values)


@pytest.fixture
def model_path(tmp_path) -> Path:
    folder = tmp_path / "models"
    folder.mkdir()
    return write_model(folder, "m.onnx", tiny_model_bytes())


def test_the_detector_decides_what_the_daemon_reports(model_path):
    """The same frames through a bare detector and through the daemon's ``handle_frame``: the same
    classes at the same frames with the same scores (the daemon adds only the event line around them)."""
    rec = _pushes()
    detector = Detector(trigger=TriggerConfig(kind="threshold"))
    detector.swap(load_model(model_path), rec.layout)
    decisions = [d for d in map(detector.feed, _frames(rec)) if d is not None]
    events: list[Event] = []
    daemon = Daemon(config_from_dict({"sinks": {"stdout": False}, "trigger": {"kind": "threshold"}}),
                    on_event=events.append)
    daemon.serve(load_model(model_path), rec.layout)
    for frame in _frames(rec):
        daemon.handle_frame(frame)
    assert len(decisions) == 2 and all(d.problem is None and d.latency_us > 0 for d in decisions)
    assert [(d.cls, d.first, d.frame.number) for d in decisions] == [(e.cls, e.frame_first, e.frame_last) for e in events]
    assert [d.scores[0].tolist() for d in decisions] == [list(e.scores.values()) for e in events]
    assert daemon.health.decisions == 2 and daemon.health.events == 2


def test_the_report_rule_reports_only_event_classes_and_continuous_mode_only_what_it_confirms():
    classes = ("pull", "push", "hold", "bump", "idle")
    scores = np.zeros(5, dtype=np.float32)
    rule = ReportRule(classes, ("pull", "push"))
    assert [rule.judge(i, scores) for i in range(5)] == [0, 1, -1, -1, -1]  # hold, bump and dormant are not events
    confirm = ReportRule(classes, ("pull", "push", "hold", "bump"), ContinuousDecision(5, 4, confirm_frames=2, rearm_frames=1))
    assert [confirm.judge(label, scores) for label in (0, 0, 0, 4, 1, 1)] == [-1, 0, -1, -1, -1, 1]
    confirm.reset()
    assert confirm.judge(1, scores) == -1 and confirm.judge(1, scores) == 1


def test_windows_end_in_order_and_a_frame_past_one_drops_it():
    windows = Windows()
    windows.open(14)
    windows.open(20)
    assert not windows.ends(13) and windows.ends(14) and len(windows) == 1
    assert not windows.ends(21) and len(windows) == 0  # a frame never seen (skipped) drops its window
    windows.open(30)
    assert windows.clear() == 1 and not windows



def test_windows_say_what_runs_at_a_frame_without_changing_and_a_frame_past_one_leaves_the_next_ones_heads():
    """``Windows.runs_at``, the one rule ``feed`` applies and the rehearsal asks ahead: the ring must hold a
    window, an early head answers only a window the arm has not moved in, a window's end is dormant when
    it has; a window whose last frame never came is dropped and the next one's heads still answer."""
    never = -(1 << 62)
    windows = Windows()
    windows.T, windows.early = 15, EarlyRule(EarlySpec((4, 8), ((1.0, 0.0), (1.0, 0.0)), 0.5, False), ("pull",))
    windows.open(20)  # frames 6..20
    windows.open(28)  # frames 14..28: its heads at frames 17 and 21
    assert windows.runs_at(9, 15, never) == 0 and windows.runs_at(13, 15, never) == 1
    assert windows.runs_at(9, 14, never) is None  # the ring does not hold a window yet
    assert windows.runs_at(9, 15, 6) is None and windows.runs_at(9, 15, 5) == 0  # an arm move in it: wait for its end
    assert windows.runs_at(20, 15, 5) is Run.FULL and windows.runs_at(20, 15, 6) is Run.DORMANT
    assert windows.runs_at(17, 15, never) is None  # the second window's heads wait while the first is open
    assert windows.runs_at(21, 15, never) == 1 and windows.runs_at(21, 15, 14) is None  # frame 20 never came
    assert len(windows) == 2  # asking changed nothing
    assert not windows.ends(21) and len(windows) == 1 and windows.runs_at(28, 15, 13) is Run.FULL
    every = Windows()
    every.T, every.every_frame = 15, True  # continuous mode: every frame ends a window
    assert every.runs_at(100, 15, 85) is Run.FULL and every.runs_at(100, 15, 86) is Run.DORMANT
    assert every.runs_at(100, 14, never) is None and not every

def test_a_grasp_message_is_applied_at_the_next_frame_and_survives_a_model_of_the_same_kind(model_path):
    detector = Detector(trigger=TriggerConfig(kind="onset"))
    detector.swap(load_model(model_path), LAYOUT)
    detector.set_grasp(True, source="test")
    assert detector.grasp_request == (True, "test") and detector.grasp_closed is None  # queued only
    detector.feed(Frame(0, 0, time.perf_counter(), np.zeros(LAYOUT.n_taxels, dtype=np.uint16)))
    assert detector.grasp_closed is True


def test_continuous_mode_decides_every_frame_once_the_ring_holds_a_window(tmp_path):
    folder = tmp_path / "models"
    folder.mkdir()
    path = write_model(folder, "m.onnx", tiny_model_bytes(weights=(0.01, -0.01, 0.0, 0.0), dormant_class="hold"))
    rec = _pushes()
    detector = Detector(SceneConfig(events=("pull", "push", "bump"), mode="continuous"),
                        continuous=ContinuousConfig(confirm_frames=1, rearm_frames=0))
    detector.swap(load_model(path), rec.layout)
    decisions = [d for d in map(detector.feed, _frames(rec)) if d is not None]
    assert len(decisions) == rec.n_frames - 15 + 1
    assert {d.cls for d in decisions} <= {None, "pull", "push", "bump"}  # the dormant class is never reported


def _daemon_with_a_window_open(folder: Path) -> Daemon:
    """A daemon fed a push until a window is open (its last frame still to come)."""
    folder.mkdir(exist_ok=True)
    write_model(folder, "m.onnx", tiny_model_bytes())
    daemon = Daemon(config_from_dict({"sinks": {"stdout": False}}))
    daemon.serve(load_model(folder / "m.onnx"), LAYOUT)
    for frame in _frames(_pushes()):
        daemon.handle_frame(frame)
        if daemon.detector.window_open:
            return daemon
    raise AssertionError("no window opened")


def test_a_reconnect_or_a_model_swap_mid_window_drops_the_open_window(tmp_path):
    daemon = _daemon_with_a_window_open(tmp_path)
    daemon.detector.fit(LAYOUT)  # the device reconnected (same layout): the history is forgotten
    other = _daemon_with_a_window_open(tmp_path / "b")
    other.models.use(load_model(tmp_path / "m.onnx"))  # SIGHUP or the watcher swapped a model in
    assert not daemon.detector.window_open and not other.detector.window_open
    assert daemon.detector.ring.count == 0


def test_windows_that_keep_opening_hold_a_swap_or_reload_back_at_most_the_limit(tmp_path, caplog):
    """A trigger that fires all the time (refractory_s = 0, rearm_quiet_s = 0) always has a window open:
    a dropped-in model and a SIGHUP waited for ever (the attacker's reload storm). They wait for the
    open windows' decisions at most HOLD_LIMIT_S; then those windows are dropped, in one warning."""
    from runtime.daemon import HOLD_LIMIT_S

    daemon = _daemon_with_a_window_open(tmp_path)
    models = tmp_path / "models"
    models.mkdir()
    daemon.models.cfg = replace(daemon.cfg, model=replace(daemon.cfg.model, folder=str(models), poll_interval_s=60))
    daemon.models.start()
    write_model(models, "newer.onnx", tiny_model_bytes(tag="newer"))
    daemon.models.watcher.poll(require_stable=False)
    assert daemon.models.pending
    t = 1000.0
    daemon.take_pending_model(t)
    daemon.take_pending_model(t + HOLD_LIMIT_S / 2)
    assert Path(daemon.model.path).name == "m.onnx" and daemon.detector.window_open
    with caplog.at_level("WARNING", logger="handover"):
        daemon.take_pending_model(t + HOLD_LIMIT_S)
    daemon.models.stop()
    assert Path(daemon.model.path).name == "newer.onnx" and not daemon.detector.window_open
    assert "dropped undecided" in caplog.text and "refractory_s" in caplog.text
    assert not daemon.windows_hold(t + 2 * HOLD_LIMIT_S)  # nothing open: nothing held, the clock restarts
    other = _daemon_with_a_window_open(tmp_path / "b")
    assert other.windows_hold(t + 3 * HOLD_LIMIT_S)  # a fresh hold starts its own clock


def test_a_model_dropped_while_the_device_is_away_serves_at_once_though_a_window_was_open(tmp_path):
    """The link failed with a window open: its last frames never come (the reconnect restarts the
    history), yet it held the model dropped during the outage back until the device was back or
    HOLD_LIMIT_S (10 s) passed; the soak's rollback in that time removed the file before it served."""
    from firmware_io.transports import DeviceUnavailable

    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes())
    away = threading.Event()

    class UnpluggedMidWindow:
        """Streams two pushes; unplugged (and gone) once a window is open, as a model is dropped."""

        def __init__(self) -> None:
            self.frames = _frames(_pushes())

        def open(self, should_stop=None) -> SensorLayout:
            if away.is_set():  # the link reopens the client it has
                raise DeviceUnavailable("cannot connect: Connection refused")
            return LAYOUT

        def start(self, should_stop=None) -> None:
            pass

        def read_frame(self, timeout: float) -> Frame | None:
            if daemon.detector.window_open:
                away.set()
                write_model(models, "newer.onnx", tiny_model_bytes(tag="newer"))
                raise ConnectionError("unplugged")
            return next(self.frames, None)

        def close(self, stop_timeout=None) -> None:
            pass

    cfg = config_from_dict({"device": {"url": "tcp://127.0.0.1:9", "reconnect_min_s": 0.05, "reconnect_max_s": 0.2},
                            "model": {"folder": str(models), "poll_interval_s": 0.05}, "sinks": {"stdout": False}})
    daemon = Daemon(cfg, client_factory=lambda url: UnpluggedMidWindow())
    runner = threading.Thread(target=daemon.run, daemon=True)
    runner.start()
    try:
        served = wait_for(lambda: away.is_set() and Path(daemon.model.path).name == "newer.onnx", timeout=3.0)
    finally:
        daemon.request_stop()
        runner.join(timeout=5)
    assert served and not daemon.link.connected


def _nan_when_pressed_at(rate_hz: float) -> bytes:
    """A continuous-mode model at ``rate_hz`` that passes every static check but answers NaN scores
    (sqrt of a negative number) once the frames' mean exceeds 1, i.e. on the first press."""
    import json

    import onnx
    from onnx import helper

    graph = onnx.load_from_string(tiny_model_bytes(weights=(-1.0, 0.0, 0.0, 0.0), bias=(1.0, 0.0, 0.0, 0.0),
                                                   dormant_class="hold"))
    add = next(n for n in graph.graph.node if n.op_type == "Add")
    add.output[0] = "before_sqrt"
    graph.graph.node.append(helper.make_node("Sqrt", ["before_sqrt"], ["scores"]))
    graph.graph.node.sort(key=lambda n: n.op_type == "ArgMax")  # ArgMax last: it reads the scores
    for prop in graph.metadata_props:
        meta = json.loads(prop.value)
        meta["sample_rate_hz"] = rate_hz
        prop.value = json.dumps(meta)
    return graph.SerializeToString()


def test_a_broken_decision_is_a_problem_the_daemon_answers_with_the_fallback_on_a_new_ring(tmp_path):
    """A continuous-mode decision that breaks the output contract takes its model out of service and hands
    over to the model it replaced; at another sample rate that one starts a new, empty ring, and
    decides once it holds a window."""
    models = tmp_path / "models"
    models.mkdir()
    old = write_model(models, "old.onnx", tiny_model_bytes(dormant_class="hold"))
    new = write_model(models, "new.onnx", _nan_when_pressed_at(40.0))
    daemon = Daemon(config_from_dict({"sinks": {"stdout": False}, "scene": {"mode": "continuous"}}))
    daemon.serve(load_model(old), LAYOUT)
    daemon.serve(load_model(new, warm_up=False), LAYOUT)  # the warm-up would have caught it: a sleeper
    decided = 0
    for i in range(80):  # frames at 40 Hz; the press from frame 30 on
        values = np.full(LAYOUT.n_taxels, 500 if i >= 30 else 0, dtype=np.uint16)
        daemon.handle_frame(Frame(i, round(i * 25), time.perf_counter(), values))
        if i == 30:
            assert Path(daemon.model.path).name == "old.onnx" and daemon.health.models_quarantined == 1
            decided = daemon.health.decisions
    assert daemon.health.decisions > decided and daemon.health.frame_errors == 0


def test_continuous_mode_over_a_real_link_decides_every_frame_once_the_ring_holds_a_window(tmp_path):
    """The TCP emulator at 32 Hz in real time: a decision on every frame from the ring's first full window
    on, none skipped (the emulator's clock runs from power-on: the frames sent before the daemon connected
    are not its)."""
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.server import TcpEmulatorServer
    from runtime.listeners import FrameRecorder

    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes(weights=(0.01, -0.01, 0.0, 0.0), dormant_class="hold"))
    emulator = DeviceEmulator(_pushes(), speed=1.0, loop=False)
    server = TcpEmulatorServer(emulator).start()
    seen = FrameRecorder()
    try:
        daemon = Daemon(config_from_dict({"device": {"url": server.url}, "sinks": {"stdout": False},
                                          "model": {"folder": str(models)}, "scene": {"mode": "continuous"}}))
        daemon.listeners.append(seen)
        rehearsed, rehearse = [], daemon.detector.rehearse

        def rehearse_once() -> None:  # the loop's rehearsals, each for the frame after the newest
            rehearsed.append(daemon.detector.latest_frame.number + 1)
            rehearse()

        daemon.detector.rehearse = rehearse_once

        def stop_when_played() -> None:
            _until(lambda: emulator.finished)
            _until(lambda: daemon.health.device_faults > 0, timeout=0.5)  # the last frames read
            daemon.request_stop()

        stopper = threading.Thread(target=stop_when_played, daemon=True)
        stopper.start()
        daemon.run()
        stopper.join()
    finally:
        server.stop()
    assert len(seen.frames) > 30 and daemon.health.frames_received == len(seen.frames)
    assert [n for n, _ in seen.decisions] == seen.frames[14:]
    # each rehearsal once, for a frame that decided (or the one after the last, which never came)
    assert len(set(rehearsed)) == len(rehearsed) and set(rehearsed) <= {*seen.frames[14:], seen.frames[-1] + 1}


_until = functools.partial(wait_for, timeout=30.0)


def test_a_rehearsal_comes_just_before_each_frame_that_runs_the_model_and_changes_no_decision(model_path):
    """``rehearsal_at`` names a time inside the coming period only before a frame that ends a window;
    a detector rehearsed there decides exactly what one left alone decides."""
    rec = _pushes()
    alone, rehearsed = Detector(trigger=TriggerConfig(kind="threshold")), Detector(trigger=TriggerConfig(kind="threshold"))
    alone.swap(load_model(model_path), rec.layout)
    rehearsed.swap(load_model(model_path), rec.layout)
    assert rehearsed.rehearsal_at() is None  # no frame yet
    before, got, want = [], [], []
    for frame in _frames(rec):
        want.append(alone.feed(frame))
        got.append(rehearsed.feed(frame))
        if (at := rehearsed.rehearsal_at()) is not None:
            assert frame.received < at < frame.received + 1 / 32
            before.append(frame.number + 1)
            rehearsed.rehearse()
    decided = [d.frame.number for d in got if d is not None]
    assert len(decided) == 2 and before == decided
    assert [(d.cls, d.frame.number, d.scores.tobytes()) for d in got if d is not None] == \
        [(d.cls, d.frame.number, d.scores.tobytes()) for d in want if d is not None]


def test_a_rehearsal_that_fails_is_left_to_the_decision(model_path):
    """A model ended from outside (the decision guard) raises on every run: the rehearsal says nothing,
    the decision after it reports the problem."""
    rec = _pushes()
    detector = Detector(trigger=TriggerConfig(kind="threshold"))
    model = load_model(model_path)
    detector.swap(model, rec.layout)
    model.end_decision("ran too long")
    rehearsals, problems = 0, []
    for frame in _frames(rec):
        if (decision := detector.feed(frame)) is not None:
            problems.append(decision.problem)
        if detector.rehearsal_at() is not None:
            detector.rehearse()
            rehearsals += 1
    assert rehearsals == 2 and len(problems) == 2 and all("ran too long" in p for p in problems)


def test_every_trigger_has_every_method_the_detector_calls_on_it():
    """The detector calls ``set_grasp`` on whatever trigger serves: the ``Trigger`` protocol declares it and
    each trigger has it (no ``getattr`` probe on the hot path)."""
    from runtime.detector import Trigger
    from runtime.onset import OnsetTrigger
    from runtime.trigger import ContinuousTrigger, ThresholdTrigger

    declared = {name for name in vars(Trigger) if not name.startswith("_")} | set(Trigger.__annotations__)
    assert {"update", "reset", "set_grasp", "window", "pre_frames"} <= declared
    for trigger in (ThresholdTrigger(4, 4095.0), ContinuousTrigger(15),
                    OnsetTrigger((2, 2), 4095.0, 0.1, 0.01, 0.01, 4.0, 3, 0.02)):
        assert all(hasattr(trigger, name) for name in declared), type(trigger).__name__
        trigger.set_grasp(True)
