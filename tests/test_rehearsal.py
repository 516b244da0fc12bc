"""Keeping warm (runtime.rehearsal): the model runs once shortly before a due frame, the device is
polled instead of slept on until it arrives, and no decision changes."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from firmware_io.client import Frame
from firmware_io.layout import SensorLayout
from firmware_io.recordings.recording import Recording
from runtime.config import config_from_dict
from runtime.daemon import Daemon
from runtime.model import load_model
from runtime.rehearsal import EARLY_HISTORY, GRACE_S, LEAD_MARGIN_S, LEAD_S, MIN_LEAD_S, Rehearsal
from runtime.sinks import Event
from tests.tiny_models import tiny_model_bytes, write_model


class _Device:
    """A device read (``read(timeout)``) that delivers one item at ``perf_counter() == at``; it
    blocks like a select and notes each call's timeout and when the rehearsal ran."""

    def __init__(self, at: float | None) -> None:
        self.at, self.timeouts, self.rehearsed_at = at, [], None

    def __call__(self, timeout: float):
        self.timeouts.append(timeout)
        left = float("inf") if self.at is None else self.at - time.perf_counter()
        if left > 0 and timeout > 0:
            time.sleep(min(timeout, left))
        return "frame" if self.at is not None and time.perf_counter() >= self.at else None


def _wait(warm: Rehearsal, device: _Device, timeout: float = 0.1, limit_s: float = 5.0):
    end = time.perf_counter() + limit_s
    while time.perf_counter() < end:
        item = warm.read(device, timeout)
        if item is not None:
            return item
    return None


def test_rehearses_once_just_before_the_due_frame_then_polls_until_it_arrives():
    warm = Rehearsal()
    due = time.perf_counter() + 0.03
    device = _Device(due)
    warm.expect(due, lambda: setattr(device, "rehearsed_at", time.perf_counter()))
    assert _wait(warm, device) == "frame"
    assert warm.runs == 1 and due - LEAD_S <= device.rehearsed_at < due
    assert 0.0 in device.timeouts  # polled ...
    assert all(t <= 0.03 for t in device.timeouts)  # ... after blocking no later than the rehearsal's time
    assert 0 < warm.polled_s < LEAD_S + GRACE_S + 0.01
    warm.cancel()
    assert warm.read(device, 0.07) == "frame" and device.timeouts[-1] == 0.07  # nothing expected: a plain read


def test_the_lead_follows_how_early_due_frames_come():
    """Frames on time: the lead shrinks to MIN_LEAD_S (less polling to cool the caches again). A frame
    1 ms early: the next rehearsal ends LEAD_MARGIN_S before that. A frame much earlier than the longest
    lead is another frame (a device frame the decimation skips): it does not move the lead."""
    warm = Rehearsal()
    assert warm.lead_s == LEAD_S  # nothing measured: the longest
    for _ in range(3):
        due = time.perf_counter() + 0.005
        warm.expect(due, lambda: None)
        assert _wait(warm, _Device(due)) == "frame"
        warm.cancel()
    assert warm.lead_s == MIN_LEAD_S
    due = time.perf_counter() + 0.01
    warm.expect(due, lambda: None)
    assert _wait(warm, _Device(due - 0.001)) == "frame"  # 1 ms early, while the thread blocks
    warm.cancel()
    assert 0.0005 < warm.lead_s <= 0.001 + LEAD_MARGIN_S  # (less the clock's lateness in noticing it)
    due = time.perf_counter() + 0.02
    warm.expect(due, lambda: None)
    assert _wait(warm, _Device(due - 0.01)) == "frame"  # 10 ms early: not the due frame
    warm.cancel()
    assert warm.lead_s < 0.001 + LEAD_MARGIN_S + 1e-9
    for _ in range(EARLY_HISTORY):  # the early one ages out
        due = time.perf_counter() + 0.003
        warm.expect(due, lambda: None)
        _wait(warm, _Device(due))
        warm.cancel()
    assert warm.lead_s == MIN_LEAD_S


def test_a_slow_rehearsal_starts_early_enough_to_end_before_its_frame():
    """A model near the decision budget (3 ms at 32 Hz) rehearsed LEAD_S before the frame would
    leave the frame unread until it ends: the decision late by the overrun, unmeasured."""
    warm, late_ms = Rehearsal(), []
    for _ in range(3):
        due = time.perf_counter() + 0.02
        device = _Device(due)
        warm.expect(due, lambda: time.sleep(0.003))
        assert _wait(warm, device) == "frame"
        late_ms.append((time.perf_counter() - due) * 1e3)
    assert warm.run_s >= 0.003
    assert max(late_ms[1:]) < 0.7, late_ms  # the first, unmeasured, is late by about 1 ms


def test_a_late_frame_ends_the_polling_after_the_grace_and_a_failing_run_is_harmless():
    warm = Rehearsal()
    due = time.perf_counter() + 0.01
    device = _Device(None)  # never comes
    warm.expect(due, lambda: 1 / 0)
    started = time.perf_counter()
    while warm.due is not None and time.perf_counter() - started < 5.0:
        assert warm.read(device, 0.1) is None
    assert time.perf_counter() - started < due - started + GRACE_S + 0.05  # stopped polling at the grace
    assert warm.runs == 0 and warm.due is None
    device.timeouts.clear()
    assert warm.read(device, 0.02) is None and device.timeouts == [0.02]  # blocks as usual again


def _pushes() -> Recording:
    """Two pushes on one distal taxel, 32 Hz: frames for about 3 s."""
    layout = SensorLayout.sdh2()
    column = int(layout.columns("distal")[40])
    levels = [0] * 5 + [900] * 20 + [0] * 45 + [900] * 20
    frames = np.zeros((len(levels), layout.n_taxels), dtype=np.uint16)
    frames[:, column] = levels
    return Recording(layout, frames, np.arange(len(levels)) / 32.0)


def test_the_daemon_keeps_warm_for_each_due_frame_over_a_real_link_with_the_same_decisions(tmp_path):
    """The TCP emulator at 32 Hz in real time: one rehearsal and some polling before each decision
    (none per frame), and the decisions of the same frames handed over without waiting."""

    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes())
    rec = _pushes()
    served: list[Event] = []
    daemon = _served_in_real_time(rec, {"model": {"folder": str(models)}}, on_event=served.append)
    assert daemon.health.frames_received == rec.n_frames and len(served) == 2
    # each due frame is rehearsed for, unless a loaded machine delivered it together with the one before
    # (then it is simply read): at least one of the two, and polling around it
    assert 1 <= daemon.rehearsal.runs <= 2 and daemon.rehearsal.polled_s > 0

    replayed: list[Event] = []
    plain = Daemon(config_from_dict({"sinks": {"stdout": False}}), on_event=replayed.append)
    plain.serve(load_model(models / "m.onnx"), rec.layout)
    for i, values in enumerate(rec.frames):
        plain.handle_frame(Frame(i, round(i * 31.25), time.perf_counter(), values))
    assert [(e.cls, e.frame_last, e.scores) for e in served] == [(e.cls, e.frame_last, e.scores) for e in replayed]


def _served_in_real_time(rec: Recording, cfg: dict, listener=None, on_event=None) -> Daemon:
    """A daemon with ``cfg`` (no stdout) reading ``rec`` from the real TCP emulator at 32 Hz, until every
    frame arrived."""
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.server import TcpEmulatorServer

    server = TcpEmulatorServer(DeviceEmulator(rec, speed=1.0, loop=False)).start()
    try:
        daemon = Daemon(config_from_dict({**cfg, "device": {"url": server.url}, "sinks": {"stdout": False}}),
                        on_event=on_event)
        if listener is not None:
            daemon.listeners.append(listener)
        stopper = threading.Thread(target=lambda: (_until(lambda: daemon.health.frames_received >= rec.n_frames),
                                                   daemon.request_stop()), daemon=True)
        stopper.start()
        daemon.run()
        stopper.join()
    finally:
        server.stop()
    return daemon


def _until(condition, limit_s: float = 30.0) -> None:
    end = time.monotonic() + limit_s
    while not condition() and time.monotonic() < end:
        time.sleep(0.01)


def _daemon_with_a_due_frame_expected(folder) -> Daemon:
    """A daemon fed a push until the frame before a due one: the due frame is expected a period ahead."""
    folder.mkdir(exist_ok=True)
    write_model(folder, "m.onnx", tiny_model_bytes())
    rec = _pushes()
    daemon = Daemon(config_from_dict({"sinks": {"stdout": False}}))
    daemon.serve(load_model(folder / "m.onnx"), rec.layout)
    for i, values in enumerate(rec.frames):
        daemon.handle_frame(Frame(i, round(i * 31.25), time.perf_counter(), values))
        if daemon._pending and daemon._pending[0] == i + 1:
            assert daemon.rehearsal.due is not None
            return daemon
    raise AssertionError("no window became due")


def test_a_reconnect_or_a_model_swap_mid_window_drops_the_expectation(tmp_path):
    daemon = _daemon_with_a_due_frame_expected(tmp_path)
    daemon._fit_layout(daemon.layout)  # the device reconnected (same layout): the history is forgotten
    other = _daemon_with_a_due_frame_expected(tmp_path / "b")
    other._use_model(load_model(tmp_path / "m.onnx"))  # SIGHUP or the watcher swapped a model in
    assert daemon.rehearsal.due is None and other.rehearsal.due is None
    device = _Device(None)
    assert daemon.rehearsal.read(device, 0.01) is None and device.timeouts == [0.01] and daemon.rehearsal.runs == 0


def test_windows_that_keep_opening_hold_a_swap_or_reload_back_at_most_the_limit(tmp_path, caplog):
    """A trigger that fires all the time (refractory_s = 0, rearm_quiet_s = 0) always has a window open:
    a dropped-in model and a SIGHUP waited for ever (the attacker's reload storm). They wait for the
    open windows' decisions at most HOLD_LIMIT_S; then those windows are dropped, in one warning."""
    from runtime.daemon import HOLD_LIMIT_S

    daemon = _daemon_with_a_due_frame_expected(tmp_path)
    newer = load_model(tmp_path / "m.onnx")

    class Watcher:
        pending = newer

        def take(self):
            Watcher.pending = None
            return newer

    daemon.watcher = Watcher()
    t = 1000.0
    daemon._take_pending_model(t)
    daemon._take_pending_model(t + HOLD_LIMIT_S / 2)
    assert daemon.model is not newer and daemon.window_open and daemon.rehearsal.due is not None
    with caplog.at_level("WARNING", logger="handover"):
        daemon._take_pending_model(t + HOLD_LIMIT_S)
    assert daemon.model is newer and not daemon.window_open and daemon.rehearsal.due is None
    assert "dropped undecided" in caplog.text and "refractory_s" in caplog.text
    assert not daemon.windows_hold(t + 2 * HOLD_LIMIT_S)  # nothing open: nothing held, the clock restarts
    other = _daemon_with_a_due_frame_expected(tmp_path / "b")
    assert other.windows_hold(t + 3 * HOLD_LIMIT_S)  # a fresh hold starts its own clock


def test_the_daemons_rehearsal_warms_the_model_last(tmp_path):
    """What runs just before a due frame: the model, the output check, an event, the client's receive
    path, and the model again, so the decision's largest part is the last thing warmed."""
    daemon = _daemon_with_a_due_frame_expected(tmp_path)
    calls: list[str] = []
    run = daemon.model.run_trusted

    def counted(window):
        calls.append("model")
        return run(window)

    class Client:
        def rehearse(self) -> None:
            calls.append("receive")

    daemon.model.run_trusted = counted
    daemon.client = Client()
    daemon.rehearsal._run()
    assert calls == ["model", "receive", "model"]


def test_continuous_mode_does_not_keep_warm_and_decides_every_frame_as_a_replay(tmp_path):
    """Continuous mode decides on every frame; keeping warm for each cost 7.5-10 % of a core against the
    real emulator for 70 us a decision (runtime/rehearsal.py): it reads as before, over the real TCP
    emulator at 32 Hz, deciding the frames exactly as a replay without waiting does, garbage collected."""
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes(weights=(0.01, -0.01, 0.0, 0.0), dormant_class="hold"))
    rec = _pushes()
    decided: list[tuple[int, int]] = []

    class Decisions:
        def on_frame(self, frame) -> None:
            pass

        def on_decision(self, frame, timings) -> None:
            decided.append(frame.number)

    daemon = _served_in_real_time(rec, {"model": {"folder": str(models)}, "scene": {"mode": "continuous"}},
                                  listener=Decisions())
    n_windows = rec.n_frames - 15 + 1
    assert daemon.health.frames_received == rec.n_frames and len(decided) == n_windows
    assert daemon.rehearsal.runs == 0 and daemon.rehearsal.polled_s == 0
    assert daemon.garbage.collections >= 2  # one at start, then about one a second over 3 s

    replay = Daemon(config_from_dict({"sinks": {"stdout": False}, "scene": {"mode": "continuous"}}))
    replay.serve(load_model(models / "m.onnx"), rec.layout)
    for i, values in enumerate(rec.frames):
        replay.handle_frame(Frame(i, round(i * 31.25), time.perf_counter(), values))
    assert replay.health.decisions == daemon.health.decisions == n_windows


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


def test_continuous_mode_goes_on_deciding_when_the_fallback_starts_a_new_ring(tmp_path, caplog):
    """A continuous-mode decision that takes its model out of service hands over to the model it
    replaced; at another sample rate that one starts a new, empty ring, and decides once it holds a
    window (while continuous mode kept warm, it asked the empty ring for one: the frame's handling
    failed with 'window of 15 frames needs 15 pushed, have 0')."""
    models = tmp_path / "models"
    models.mkdir()
    old = write_model(models, "old.onnx", tiny_model_bytes(dormant_class="hold"))
    new = write_model(models, "new.onnx", _nan_when_pressed_at(40.0))
    layout = SensorLayout.sdh2()
    daemon = Daemon(config_from_dict({"sinks": {"stdout": False}, "scene": {"mode": "continuous"}}))
    daemon.serve(load_model(old), layout)
    daemon.serve(load_model(new, warm_up=False), layout)  # the warm-up would have caught it: a sleeper
    for i in range(80):  # frames at 40 Hz; the press from frame 30 on
        values = np.full(layout.n_taxels, 500 if i >= 30 else 0, dtype=np.uint16)
        daemon.handle_frame(Frame(i, round(i * 25), time.perf_counter(), values))  # raised at frame 30
        if i == 30:
            assert Path(daemon.model.path).name == "old.onnx" and daemon.health.models_quarantined == 1
            decided = daemon.health.decisions
    assert daemon.health.decisions > decided and daemon.health.frame_errors == 0
