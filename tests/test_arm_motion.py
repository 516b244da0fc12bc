"""The robot says when its arm moves: the rule (runtime.arm_motion), the control datagrams, the daemon's
windows during and after a move, the marks a recording keeps and the simulator writes."""

from __future__ import annotations

import logging
import socket

import numpy as np
import pytest

from firmware_io.recordings import arm_marks
from runtime.arm_motion import ArmMotion, arm_frames
from tests.clocks import ManualClock
from tests.datagrams import send_datagram
from tests.test_onset import _daemon, _frames, _listening, _wait, grasp_levels


def _feed(arm: ArmMotion, words: dict[int, bool], n: int) -> list[int]:
    """Frames (0..n-1) that a one-frame window would find inside the arm's motion."""
    out = []
    for i in range(n):
        if i in words:
            arm.request(words[i])
        arm.update(i)
        if _inside(arm, i):
            out.append(i)
    return out


def _inside(arm: ArmMotion, first: int) -> bool:
    """Whether the window from frame ``first`` to now holds a frame of the arm's motion (what
    ``Windows.runs_at`` judges by)."""
    return arm.last_motion >= first


def test_the_arm_counts_as_moving_from_the_message_to_the_settle_time_after_it_stops():
    arm = ArmMotion(settle_frames=3, max_move_frames=1000)
    assert _feed(arm, {10: True, 20: False}, 40) == list(range(10, 23))


def test_a_window_that_started_before_the_move_and_ends_in_it_is_judged_dormant():
    arm = ArmMotion(settle_frames=0, max_move_frames=1000)
    for i in range(30):
        if i == 25:
            arm.request(True)
        arm.update(i)
    assert _inside(arm, 30 - 15 + 1)  # window 16..30 holds frames 25..29
    arm.request(False)
    for i in range(30, 60):
        arm.update(i)
    assert not _inside(arm, 60 - 15 + 1) and _inside(arm, 30 - 15 + 1 + 10)


def test_a_lost_arm_still_does_not_deafen_the_daemon_and_says_so_once(caplog):
    arm = ArmMotion(settle_frames=2, max_move_frames=50)
    with caplog.at_level(logging.WARNING, logger="handover.daemon"):
        inside = _feed(arm, {5: True}, 200)
    assert inside == list(range(5, 57)) and not arm.moving
    assert sum("taken as still" in r.getMessage() for r in caplog.records) == 1


def test_a_repeated_arm_moving_renews_the_span():
    arm = ArmMotion(settle_frames=0, max_move_frames=50)
    words = {5: True, 40: True, 80: True, 120: False}
    assert _feed(arm, words, 200) == list(range(5, 120))


def test_settle_and_longest_move_in_frames_at_the_model_rate():
    assert arm_frames(32.0, settle_s=0.5, max_move_s=30.0) == (16, 960)  # the config's defaults
    assert arm_frames(32.0, settle_s=0.0, max_move_s=0.01) == (0, 1)
    with pytest.raises(ValueError):
        ArmMotion(-1, 10)


# -- the daemon ----------------------------------------------------------------------------------------
def _push(levels: np.ndarray, at: int) -> None:
    levels[at:at + 40, 0] *= 1.3


def test_a_push_while_the_arm_moves_is_not_reported_and_one_after_the_settle_time_is(tmp_path):
    daemon, events = _daemon(tmp_path)
    levels = grasp_levels(700)
    _push(levels, 200)  # the arm moves 190..230: this one is the arm's load, not a person
    _push(levels, 500)  # well after the arm stopped: a person
    for frame in _frames(levels):
        if frame.number == 190:
            daemon.robot.set_arm_moving(True, source="test")
        if frame.number == 230:
            daemon.robot.set_arm_moving(False, source="test")
        daemon.handle_frame(frame)
    assert len(events) == 1 and 500 <= events[0].frame_first <= 502
    assert daemon.detector.arm.dropped == 1 and daemon.detector.arm_request == (False, "test")
    daemon.write_health()
    assert daemon.health.snapshot()["arm_windows"] == 1


def test_without_the_message_the_same_push_is_reported(tmp_path):
    daemon, events = _daemon(tmp_path)
    levels = grasp_levels(700)
    _push(levels, 200)
    for frame in _frames(levels):
        daemon.handle_frame(frame)
    assert len(events) == 1 and daemon.detector.arm.dropped == 0


def test_arm_datagrams_on_the_control_socket_reach_the_hot_path_and_unknown_ones_are_one_line(tmp_path, caplog):
    with _listening(tmp_path) as (daemon, path):
        frames = _frames(grasp_levels(700))
        daemon.handle_frame(frames[0])
        send_datagram(path, b"arm moving\n")
        assert _wait(lambda: daemon.control.received == 1)
        daemon.handle_frame(frames[1])
        assert daemon.detector.arm.moving and daemon.detector.arm_request == (True, "control")
        with caplog.at_level(logging.WARNING, logger="handover.control"):
            for text in (b"arm flying", b"ARM", b"arm moving please", b"\x00" * 40):
                send_datagram(path, text)
            assert _wait(lambda: daemon.control.garbage == 4)
        assert sum("ignored a datagram" in r.getMessage() for r in caplog.records) == 1
        daemon.write_health()
        health = daemon.health.snapshot()
        assert health["control_ignored"] == 4 and health["arm_moving"] is True
        send_datagram(path, b"  ARM   STILL ")
        assert _wait(lambda: daemon.control.received == 2)
        daemon.handle_frame(frames[2])
        assert not daemon.detector.arm.moving and daemon.detector.arm.last_motion == 1 + daemon.detector.arm.settle_frames


def test_a_flood_of_arm_datagrams_is_a_few_log_lines_and_the_loop_keeps_up(tmp_path, caplog):
    with _listening(tmp_path) as (daemon, path):
        frames = _frames(grasp_levels(400))
        with caplog.at_level(logging.INFO, logger="handover.daemon"):
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
                for i in range(3000):
                    s.sendto(b"arm moving" if i % 2 else b"arm still", path)
                    if i % 10 == 0:
                        daemon.handle_frame(frames[i // 10])  # the hot path runs meanwhile, never waits
            assert _wait(lambda: daemon.control.received + daemon.control.garbage >= 2000)
        lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("arm ")]
        assert 1 <= len(lines) <= 10, lines
        assert len(daemon.detector.arm._requests) <= 64  # bounded: the newest words are kept


# -- marks with the data ---------------------------------------------------------------------------------
def _moving_frames(marks: dict[int, bool], n_frames: int) -> np.ndarray:
    """Per frame whether the robot's last word before it was ``arm moving`` (no settle time: that is the daemon's)."""
    out = np.zeros(n_frames, dtype=bool)
    state, since = False, 0
    for frame, moving in sorted(marks.items()):
        if state:
            out[since:frame] = True
        state, since = bool(moving), int(frame)
    if state:
        out[since:] = True
    return out


def test_the_simulator_marks_its_own_moves_and_they_lie_inside_its_arm_move_frames():
    from firmware_io.sim.idle import simulate_idle
    from trainer.streams_eval import source_names

    rec = simulate_idle(120.0, seed=3)
    marks = arm_marks.marks_of(rec.meta, rec.n_frames)
    moving = _moving_frames(marks, rec.n_frames)
    names = source_names(rec, rec.n_frames)
    assert moving.sum() > 0 and np.all(names[moving] == "arm_move")
    assert next(iter(marks.values())) is True and len(marks) % 2 == 0


def test_recorded_arm_move_stretches_count_as_marks_and_stored_marks_win():
    meta = {"sources": ["open", "quiet", "arm_move"], "source_codes": [1, 1, 2, 2, 2, 1, -1, 2, 2]}
    assert arm_marks.marks_of(meta, 9) == {2: True, 5: False, 7: True}
    meta[arm_marks.KEY] = arm_marks.encode({3: True, 4: False})
    assert arm_marks.marks_of(meta, 9) == {3: True, 4: False}


@pytest.mark.parametrize("bad", [{"x": 1}, [[3, 1], [2, 0]], [[3, 2]], [[99, 1]], [[True, 1]], [[1]]])
def test_marks_that_do_not_fit_the_recording_are_one_line_naming_the_key(bad):
    with pytest.raises(ValueError, match=r"meta\.arm_marks"):
        arm_marks.marks_of({arm_marks.KEY: bad}, 10)


def test_joint_speed_says_moving_and_still_on_a_change_and_repeats_moving_while_it_lasts():
    from runtime.arm_motion import JointSpeed

    js = JointSpeed(threshold=0.1, renew_s=1.0)
    words = [js.update([0.0], [v], t) for t, v in ((0.0, 0.0), (0.01, 0.5), (0.02, 0.5), (1.05, 0.4), (1.06, 0.0))]
    assert words == [False, True, None, True, False]
    assert js.update([0.0], [float("nan")], 2.0) is None  # nothing finite: positions say it, from the next message


def test_joint_speed_from_positions_when_the_driver_sends_no_velocities():
    from runtime.arm_motion import JointSpeed

    js = JointSpeed(threshold=0.1)
    assert js.update([0.0, 1.0], [], 10.0) is None  # one message: no speed yet
    assert js.update([0.0, 1.0], [], 10.1) is False
    assert js.update([0.0, 1.05], [], 10.2) is True  # 0.5 rad/s
    assert js.update([0.0, 1.05], [], 10.2) is None  # the same stamp again: no speed
    assert js.update([0.0], [], 10.3) is None  # joints changed in number: start over


# -- the recorder hears the robot ----------------------------------------------------------------------
def test_the_mark_log_places_the_robots_words_on_the_frames_that_arrived_after_them():
    clock = ManualClock()
    log = arm_marks.ArmMarkLog(clock)
    received = np.arange(10.0, 20.0)  # frames arrive at 10, 11, ... 19
    assert log.marks_for(received) == []  # nothing heard: no marks at all
    for t, word in ((5.0, True), (12.5, False), (12.6, False), (30.0, True)):
        clock.t = t
        log.note(word)
    assert log.heard == 4
    assert log.marks_for(received) == [[0, 1], [3, 0]]  # moving since before the segment; still from frame 3 (13.0)
    assert log.marks_for(np.arange(20.0, 25.0)) == [[0, 0]]  # the next segment starts still
    assert log.marks_for(None) == []


def test_a_recorded_session_stores_the_robots_arm_words_heard_on_the_control_socket(tmp_path):
    from firmware_io.recordings.idle_session import run_idle
    from firmware_io.recordings.idle_stretches import IdleSlot
    from firmware_io.recordings.record_session import SessionIO
    from firmware_io.recordings.recording import Recording
    from firmware_io.sim.scripted_subject import ScriptedSubject
    from runtime.control import ControlSocket
    from tests.test_record import auto_opts, open_session

    subject = ScriptedSubject(seed=4, speed=10.0)
    client, store = open_session(tmp_path, subject)
    path = str(tmp_path / "robot.sock")
    log = arm_marks.ArmMarkLog()
    control = ControlSocket(path, on_grasp=lambda closed, source: None, on_arm=log.note).start()
    words = {0: b"arm moving", 1: b"arm still"}

    def cue(kind, slot):  # the robot speaks as each stretch starts
        subject.cue(kind, slot)
        if kind == "idle":
            send_datagram(path, words[slot.index])
            assert _wait(lambda: log.heard == slot.index + 1)

    try:
        plan = [IdleSlot(0, "arm_move", 1.5), IdleSlot(1, "quiet", 1.5)]
        result = run_idle(client, store, plan, auto_opts(arm_log=log), SessionIO(cue=cue, sleep=lambda s: None))
    finally:
        control.stop()
        client.close()
    assert result.complete
    rec = Recording.load(store.path)
    marks = arm_marks.marks_of(rec.meta, rec.n_frames)
    stretches = rec.meta["idle_stretches"]
    moving = _moving_frames(marks, rec.n_frames)
    first, second = stretches[0], stretches[1]
    assert moving[first["first"] + 5:first["last"] + 1].all() and not moving[:first["first"]].any()
    assert moving[second["first"]] and not moving[second["first"] + 5:].any()  # still a few frames in


def test_record_with_a_control_socket_that_cannot_bind_is_one_line(tmp_path, capsys):
    from tests.test_record import record

    code = record(tmp_path, "--auto", "--control", str(tmp_path / "missing" / "robot.sock"))
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "robot.sock" in err[0], err


def test_a_piece_of_a_recording_keeps_its_marks_and_the_state_it_starts_in():
    meta = {arm_marks.KEY: [[2, 1], [6, 0], [8, 1]]}
    assert arm_marks.piece_marks(meta, 10, 4, 9) == [[0, 1], [2, 0], [4, 1]]
    assert arm_marks.piece_marks(meta, 10, 6, 7) == []
    assert arm_marks.piece_marks({}, 10, 0, 9) == []


def test_a_device_count_that_starts_afresh_does_not_leave_the_daemon_deaf_to_a_past_arm_move(tmp_path):
    """A new device client (another device URL on SIGHUP) counts frames from 0 again: an arm move
    said at frame 100190 of the old count must not hold every window of the new one."""
    import dataclasses

    from tests.test_onset import LAYOUT

    daemon, events = _daemon(tmp_path)
    for frame in _frames(grasp_levels(300)):
        frame = dataclasses.replace(frame, number=frame.number + 100_000)
        if frame.number in (100_190, 100_230):
            daemon.robot.set_arm_moving(frame.number == 100_190, source="test")
        daemon.handle_frame(frame)
    daemon.detector.fit(LAYOUT)
    levels = grasp_levels(700)
    _push(levels, 500)
    for frame in _frames(levels):
        daemon.handle_frame(frame)
    assert len(events) == 1 and 500 <= events[0].frame_first <= 502 and daemon.detector.arm.dropped == 0


def test_a_count_that_starts_afresh_keeps_the_settle_time_and_a_move_in_progress():
    arm = ArmMotion(settle_frames=5, max_move_frames=50)
    assert _feed(arm, {95: True}, 100) == list(range(95, 100))
    inside = []
    for i in range(60):  # numbers from 0 again; still moving, expires 50 frames after 'arm moving'
        arm.update(i)
        if _inside(arm, i):
            inside.append(i)
    assert inside == list(range(0, 45 + 5))


def test_the_labs_replay_uses_the_robots_stored_marks_not_only_the_arm_move_stretches(tmp_path):
    """A recording made with ``record --control``: the robot said the arm moved over a stretch labelled
    quiet; the held-out replay with the arm messages judges that push dormant, without them it is false."""
    from firmware_io.layout import SensorLayout
    from firmware_io.recordings.idle_stretches import idle_meta
    from firmware_io.recordings.recording import Recording
    from tests.test_onset import _onset_model
    from trainer.own_replay import replay_recording

    levels = grasp_levels(500)
    _push(levels, 200)
    frames = np.stack([f.values for f in _frames(levels)])
    meta = idle_meta(len(frames), [{"first": 0, "last": len(frames) - 1, "source": "quiet", "index": 0}])
    meta[arm_marks.KEY] = [[190, 1], [230, 0]]
    rec = Recording(SensorLayout.sdh2(), frames, np.arange(len(frames)) / 32.0, [], meta)
    out = replay_recording(rec, _onset_model(tmp_path), "onset")
    assert out["false_by_source"] == {"quiet": 1} and out["false_by_source_arm_messages"] == {}


def test_joint_speed_keeps_renewing_moving_when_the_stamps_go_back():
    """A bag played in a loop (or sim time reset) restarts the stamps: 'moving' is still renewed every
    second, else the daemon's arm would expire after arm_max_move_s while the arm moves."""
    from runtime.arm_motion import JointSpeed

    js = JointSpeed(threshold=0.1, renew_s=1.0)
    assert js.update([0.0], [0.5], 100.0) is True
    said = [js.update([0.0], [0.5], 0.5 * k) for k in range(1, 8)]  # stamps from 0.5 s again, arm moving
    assert said.count(True) >= 3 and said[0] is True
