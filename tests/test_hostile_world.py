"""The daemon in a hostile world: nothing it writes blocks the thread that reads the pads, nothing
outside its user steers it, nothing a file claims is taken on trust. Each case of
benchmarks/hostile_world.py runs here with real parts; ``./dev bench hostile`` counts them."""

from __future__ import annotations

import os
import threading

import pytest

pytest.importorskip("onnx")
W = pytest.importorskip("benchmarks.hostile_world")


def _held(result: dict) -> None:
    assert result["held"], result["detail"]


# Each case runs the world's parts for real and says whether it held; the id says what must hold.
@pytest.mark.parametrize("case", [
    pytest.param("blocked_stdout", id="a_stdout_nobody_reads_never_stops_detection_nor_the_udp_sink"),
    pytest.param("blocked_stdout_process", id="handover_run_into_a_pipe_nobody_reads_keeps_sending_udp_and_ends_on_sigterm", marks=pytest.mark.slow),
    pytest.param("closed_stdout", id="stdout_closed_at_start_is_one_line_or_no_stdout_sink_never_a_crash"),
    pytest.param("silent_dns", id="a_udp_host_whose_dns_is_silent_never_holds_ready_or_sighup"),
    pytest.param("control_paths", id="a_control_socket_path_that_cannot_work_is_one_line_at_check_and_at_run"),
    pytest.param("state_file_paths", id="a_health_or_quarantine_file_naming_a_folder_is_one_line_at_check_run_and_sighup"),
    pytest.param("partial_config", id="sighup_on_an_empty_cut_or_fifo_config_keeps_the_running_one_with_one_line"),
    pytest.param("crafted_dsa", id="crafted_dsa_files_are_one_line_and_never_allocate_what_the_header_asks"),
    pytest.param("model_claims", id="the_model_metadata_is_not_believed_where_the_stream_says_otherwise"),
    pytest.param("folder_rollbacks", id="what_the_model_folder_holds_is_what_is_served_and_check_agrees"),
    pytest.param("hanging_model_process", id="handover_run_with_a_hanging_model_serves_the_old_one_and_ends_on_sigterm", marks=pytest.mark.slow),
    pytest.param("layout_comes_back", id="a_controller_back_with_another_layout_then_the_original_gets_its_model_back"),
    pytest.param("controller_reset_behind_tcp", id="a_controller_applies_its_threshold_resets_behind_tcp_and_keeps_a_persistent_write"),
    pytest.param("files_that_eat", id="files_that_eat_the_machine_are_one_line_within_5_s_and_500_mb", marks=pytest.mark.slow),
    pytest.param("full_disk_record", id="record_on_a_full_disk_says_what_was_saved_resumes_and_leaves_no_temp_file",
                 marks=pytest.mark.slow),
    pytest.param("squatted_control_name", id="a_control_name_another_user_holds_is_exit_2_and_a_reload_never_lets_go_of_it"),
    pytest.param("squatted_lock_folder", id="another_users_lock_folder_is_refused_in_one_line_and_nothing_is_written_there"),
    pytest.param("device_spellings", id="one_device_however_spelled_is_one_lock"),
    pytest.param("unwritable_health_folder", id="a_health_folder_the_daemon_cannot_write_fails_check_as_it_fails_run"),
    pytest.param("lying_early_heads", id="early_heads_that_contradict_the_full_model_are_disabled_with_a_note"),
])
def test_the_case_holds(case, tmp_path):
    _held(getattr(W, case)(tmp_path))


def test_the_stdout_sink_keeps_whole_lines_and_counts_what_it_dropped():
    from runtime.sinks import StdoutSink

    read_end, write_end = os.pipe()
    sink = StdoutSink(os.fdopen(write_end, "w"), backlog_bytes=1000)
    line = '{"type":"decision","pad":"' + "x" * 90 + '"}'
    done = threading.Event()

    def flood() -> None:
        for _ in range(2000):  # 190 KB into a 64 KB pipe nobody reads
            sink.send(line, line.encode())
        done.set()

    threading.Thread(target=flood, daemon=True).start()
    assert done.wait(30), "a send blocked on a full pipe"
    assert sink.dropped > 0 and sink.errors == sink.dropped
    os.set_blocking(read_end, False)
    text = os.read(read_end, 1 << 20).decode()
    sink.flush()  # room again: the backlog follows
    text += os.read(read_end, 1 << 20).decode()
    lines = text.splitlines()
    assert set(lines) == {line} and text.endswith("\n")
    assert len(lines) + sink.dropped == 2000
    sink.close()
    assert os.get_blocking(write_end)  # the descriptor's mode is given back
    os.close(read_end)


def test_a_udp_address_literal_needs_no_lookup_and_a_name_is_looked_up_off_the_caller():
    import socket

    from runtime.sinks import UdpSink

    calls = []
    release = threading.Event()

    def dns(host, port, **kw):
        calls.append(host)
        release.wait()
        raise socket.gaierror(socket.EAI_AGAIN, "Temporary failure in name resolution")

    literal = UdpSink("127.0.0.1", 9, resolve=dns)
    assert literal.address is not None and not calls
    named = UdpSink("robot-pc.example", 9, resolve=dns)  # returns while the lookup hangs
    named.send("x", b"x")
    assert named.errors == 1 and named.sent == 0
    release.set()
    named.close()
    literal.close()


def test_only_the_daemons_user_or_root_may_steer_it_and_ros2_grasp_is_off_and_named(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("sending as another user needs root")
    _held(W.foreign_grasp(tmp_path))


def test_the_sender_credentials_rule():
    from runtime.control_access import may_steer

    assert may_steer(1000, own_uid=1000) and may_steer(0, own_uid=1000)
    assert not may_steer(65534, own_uid=1000) and not may_steer(None, own_uid=1000)


def test_a_config_is_read_whole_from_a_regular_file_and_a_fifo_is_refused_at_once(tmp_path):
    from runtime.config import read_whole

    path = tmp_path / "h.toml"
    path.write_text('[device]\nurl = "sim://"\n')
    assert read_whole(path) == path.read_bytes()
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    with pytest.raises(OSError, match="not a regular file"):
        read_whole(fifo)


def test_a_model_that_hangs_on_real_windows_is_ended_from_outside_and_stays_out(tmp_path):
    result = W.hanging_model(tmp_path)
    assert result["held_untimed"], result["detail"]  # its time is the benchmark's to report


def test_the_guard_ends_a_real_hanging_decision_when_its_clock_says_so(tmp_path):
    import numpy as np

    from benchmarks import hostile_models as H
    from runtime.decision_guard import DecisionGuard
    from runtime.model import DecisionEnded, load_model

    path = tmp_path / "hang.onnx"
    path.write_bytes(H.hang())
    model = load_model(path)  # passes warm-up
    window = np.zeros((1, H.T, sum(H.PAD_SIZES)), dtype=np.float32)
    window[0, 3, 7] = H.SLEEPER_PEAK
    outcome = []

    def decide() -> None:
        try:
            model.run_trusted(window)
        except DecisionEnded as exc:
            outcome.append(str(exc))

    exits = []
    guard = DecisionGuard(lambda: model, lambda: 0.03125, exit=exits.append)
    thread = threading.Thread(target=decide, daemon=True)
    thread.start()
    while (cpu := model.decision_cpu_s()) is None or cpu <= 0.04:  # the hanging graph spends CPU time
        thread.join(0.005)
    guard.check(model.running_since + 0.04)
    thread.join(30)
    assert not thread.is_alive() and guard.ended == 1 and "31.2 ms" in outcome[0] and not exits


class _Waiting:
    """A decision under way whose thread has waited for a core rather than computed."""

    model_id = "waiting"
    running_since = 100.0
    ended = None

    def decision_cpu_s(self) -> float:
        return 0.002

    def end_decision(self, reason: str) -> None:
        self.ended = reason


def test_the_guard_leaves_a_decision_that_only_waited_for_a_core_until_its_wall_limit():
    from runtime.decision_guard import WALL_LIMIT_S, DecisionGuard

    model = _Waiting()
    guard = DecisionGuard(lambda: model, lambda: 0.03125, exit=lambda code: None)
    guard.check(model.running_since + 0.5)  # 16 periods late, 2 ms computed: a busy machine, not the model
    assert model.ended is None and guard.ended == 0
    guard.check(model.running_since + WALL_LIMIT_S + 0.01)  # the backstop
    assert model.ended is not None and "had not ended" in model.ended and guard.ended == 1


def test_the_device_rate_counts_frames_dropped_as_implausible():
    from runtime.health import Health

    h = Health()
    counts = {"frames_received": 0, "frames_implausible": 0}
    h.parts = [lambda: counts]
    h.update_rate(now=h._rate_t)
    counts.update(frames_received=22, frames_implausible=10)  # 32 frames a second, 10 of them above 4095
    h.update_rate(now=h._rate_t + 1.0)
    assert h.frame_rate == 32.0


def test_no_model_serving_is_the_health_views_error(tmp_path):
    from runtime.config import config_from_dict
    from runtime.daemon import Daemon

    daemon = Daemon(config_from_dict({"device": {"url": "sim://"}, "sinks": {"stdout": False},
                                      "model": {"folder": str(tmp_path)}}))
    daemon.models.start()
    daemon.models.stop()
    assert daemon.model is None and "no model serves" in daemon.health.snapshot()["last_error"]


def test_a_model_that_hangs_at_warm_up_is_refused_in_one_line(tmp_path):
    from benchmarks import hostile_models as H
    from runtime.model import ModelContractError, load_model

    path = tmp_path / "hangs-on-any-press.onnx"
    path.write_bytes(H.hang(peak=None))
    model = load_model(path, warm_up=False)
    with pytest.raises(ModelContractError, match=r"warm-up ran longer than 0\.5 s") as info:
        model.warm_up(bound_s=0.5)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
