"""Hostile models, corrupt frames and bad numbers (issue #19): the daemon never crashes and never
emits invalid output. The fast subset of ``./dev bench hostile`` (benchmarks/hostile.py),
whose full run is marked slow here and writes results/hostile.json."""

from __future__ import annotations

import json
import logging
import math
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from firmware_io.layout import SensorLayout
from runtime.config import config_from_dict
from runtime.daemon import Daemon
from runtime.listeners import FrameListener
from runtime.model import ModelContractError, load_model
from runtime.model_watch import ModelWatcher
from runtime.sinks import Event
from tests.tiny_models import write_model

pytest.importorskip("onnx")
H = pytest.importorskip("benchmarks.hostile_models")
ROOT = Path(__file__).resolve().parents[1]


def _daemon(folder: Path, state: Path, events: list[Event] | None = None, **model) -> Daemon:
    cfg = config_from_dict({"device": {"url": "sim://"}, "sinks": {"stdout": False},
                            "model": {"folder": str(folder), "poll_interval_s": 0.05, **model},
                            "health_file": str(state / "status.json")})
    return Daemon(cfg, on_event=None if events is None else events.append)


def _press(daemon: Daemon, level: int, first: int = 0, n: int = 40) -> None:
    """A pressed distal taxel at ``level`` for 20 frames, then 20 quiet frames, through the hot path."""
    from firmware_io.client import Frame

    layout = daemon.detector.layout
    column = int(layout.columns("distal")[40])
    for i in range(first, first + n):
        values = np.zeros(layout.n_taxels, dtype=np.uint16)
        values[column] = level if i - first < 20 else 0
        daemon.handle_frame(Frame(i, round(i * 31.25), time.perf_counter(), values))


def _start(daemon: Daemon) -> None:
    daemon.detector.fit(SensorLayout.sdh2())
    daemon.models.start()
    daemon.models.watcher.stop()


@pytest.fixture
def folders(tmp_path):
    models, state = tmp_path / "models", tmp_path / "state"
    models.mkdir()
    state.mkdir()
    return models, state


@pytest.mark.parametrize("attack", sorted(H.RUNTIME_ATTACKS))
def test_warm_up_on_pressed_windows_refuses_a_model_right_only_on_empty_pads(tmp_path, attack):
    path = tmp_path / f"{attack}.onnx"
    path.write_bytes(H.RUNTIME_ATTACKS[attack]())
    load_model(path, warm_up=False)  # passes every static check of the contract
    with pytest.raises(ModelContractError, match=r"breaks the output contract on warm-up window") as info:
        load_model(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("attack", sorted(H.RUNTIME_ATTACKS))
def test_inspect_and_run_check_catch_it(folders, attack):
    models, state = folders
    path = write_model(models, "bad.onnx", H.RUNTIME_ATTACKS[attack]())
    inspect = subprocess.run([sys.executable, "-m", "runtime.cli", "inspect", str(path)], capture_output=True,
                             text=True, cwd=ROOT, timeout=60)
    assert inspect.returncode != 0 and inspect.stdout == ""
    assert len(inspect.stderr.strip().splitlines()) == 1 and "output contract" in inspect.stderr
    config = state / "handover.toml"
    config.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\n')
    check = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(config), "--check",
                            "--require-model"], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert check.returncode == 1 and "output contract" in check.stderr, check.stderr


@pytest.mark.parametrize("attack", sorted(H.RUNTIME_ATTACKS))
def test_a_sleeper_is_taken_out_of_service_once_and_stays_out_across_a_restart(folders, caplog, attack):
    """Passes the warm-up, breaks the contract on a real press: one line, the previous model serves
    again, no event is emitted from the broken decision, and a restarted daemon does not load it."""
    models, state = folders
    write_model(models, "old.onnx", H.valid(bias_class=1, tag="old"), mtime=time.time() - 60)
    write_model(models, "new.onnx", H.sleeper(attack))
    events: list[Event] = []
    daemon = _daemon(models, state, events)
    _start(daemon)
    assert Path(daemon.model.path).name == "new.onnx"
    _press(daemon, level=int(H.SLEEPER_PEAK))
    lines = [r for r in caplog.records if "taken out of service" in r.getMessage()]
    assert len(lines) == 1 and "new.onnx" in lines[0].getMessage() and daemon.model is None
    daemon.models.watcher.poll()  # the watcher thread's next scan: the next newest valid file
    daemon._housekeeping(time.monotonic())
    assert events == [] and Path(daemon.model.path).name == "old.onnx"
    assert daemon.health.models_quarantined == 1 and "new.onnx" in daemon.health.last_error
    _press(daemon, level=int(H.SLEEPER_PEAK), first=200)
    assert [e.cls for e in events] == ["push"]  # the old model decides; nothing invalid went out
    assert all(math.isfinite(s) for e in events for s in e.scores.values())

    restarted = _daemon(models, state)
    _start(restarted)
    assert Path(restarted.model.path).name == "old.onnx"
    assert any("taken out of service earlier" in r.reason for r in restarted.models.watcher.rejections)
    config = state / "handover.toml"
    config.write_text(f'health_file = "{state / "status.json"}"\n[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\n')
    check = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(config), "--check"],
                           capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert check.returncode == 0 and "(old.onnx)" in check.stdout, check.stdout + check.stderr
    write_model(models, "new.onnx", H.valid(bias_class=2, tag="fixed"))  # a new file is tried again
    assert restarted.models.watcher.poll(require_stable=False) is not None


def test_with_no_previous_model_none_serves_and_health_says_so(folders):
    models, state = folders
    write_model(models, "only.onnx", H.sleeper("label_out_of_range"))
    daemon = _daemon(models, state)
    _start(daemon)
    _press(daemon, level=int(H.SLEEPER_PEAK))
    snap = daemon.health.snapshot()
    assert daemon.model is None and snap["model_id"] is None and snap["models_quarantined"] == 1
    assert "only.onnx taken out of service" in snap["last_error"] and "outside 0..3" in snap["last_error"]
    _press(daemon, level=int(H.SLEEPER_PEAK), first=200)  # frames keep flowing, nothing is classified
    assert daemon.health.decisions == 0


def test_an_exception_in_handle_frame_never_ends_the_loop(folders, caplog):
    models, state = folders
    write_model(models, "m.onnx", H.valid())
    daemon = _daemon(models, state)
    class Flaky(FrameListener):  # a fault inside the real handle_frame, every third frame
        def on_frame(self, frame):
            if frame.number % 3 == 0:
                raise IndexError("list index out of range")

    daemon.listeners.append(Flaky())

    def stop_after_errors():
        deadline = time.monotonic() + 30
        while daemon.health.frame_errors < 20 and time.monotonic() < deadline:
            time.sleep(0.01)
        daemon.request_stop()

    threading.Thread(target=stop_after_errors, daemon=True).start()
    assert daemon.run() == 0
    h = daemon.health
    assert h.frame_errors >= 20 and h.frames_received >= 2 * (h.frame_errors - 1)
    assert len([r for r in caplog.records if "frame handling failed" in r.getMessage()]) == 1
    status = json.loads((state / "status.json").read_text())
    assert status["frame_errors"] == h.frame_errors


def test_a_model_over_the_decision_budget_is_refused_with_time_and_budget(tmp_path, caplog):
    path = tmp_path / "slow.onnx"
    path.write_bytes(H.slow(4000))
    watcher = ModelWatcher(tmp_path, loader=lambda p: load_model(p, warm_up=False), decision_budget=0.002)
    assert watcher.poll(require_stable=False) is None
    (reason,) = [r.reason for r in watcher.rejections]
    assert "ms at warm-up" in reason and "over the budget of 0.06 ms" in reason, reason
    ok = ModelWatcher(tmp_path, loader=lambda p: load_model(p, warm_up=False), decision_budget=None)
    assert ok.poll(require_stable=False) is not None  # the same file is fine without a budget
    load_model(path)  # offline tools (export, compare, bench) measure speed themselves: no budget
    config = tmp_path / "h.toml"
    config.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{tmp_path}"\ndecision_budget = 0.002\n')
    check = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(config), "--check",
                            "--require-model"], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert check.returncode == 1 and "over the budget of 0.06 ms" in check.stderr, check.stderr


def test_onnxruntime_failure_banner_never_reaches_stdout(tmp_path, capsys):
    """A damaged operator name (invalid UTF-8) made onnxruntime's Python wrapper print an
    "EP Error" banner to stdout, the daemon's JSON-lines event stream, before it retried."""
    path = tmp_path / "bad.onnx"
    path.write_bytes(H.ort_banner())
    with pytest.raises(ModelContractError, match="onnxruntime cannot load it") as info:
        load_model(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    out = capsys.readouterr().out
    assert out == "", out


def test_mutated_model_files_are_refused_with_one_line_naming_the_file(tmp_path):
    path = tmp_path / "mutant.onnx"
    base = H.valid()
    for data in H.mutations(base, 150, seed=7):
        path.write_bytes(data)
        try:
            load_model(path)
        except ModelContractError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc)


def test_frames_the_sensor_cannot_send_are_counted_and_dropped():
    """CRC-valid frames with a value above 12 bits or pressure on a missing cell (what multi-bit
    errors the CRC lets through look like) never leave the client."""
    from firmware_io.client import DSAClient
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.frame_source import load_source
    from firmware_io.recordings.recording import Recording
    from firmware_io.transports.emulated import EmulatedTransport

    rec = load_source("sim", seed=3, events=2)
    frames = rec.frames[:60].copy()
    frames[10, 100] = 32768
    frames[20, 5] = 4096
    dead = 84  # matrix 1 (distal) starts at 84; its cell (0, 0) does not exist
    frames[30, dead] = 700
    bad = {10, 20, 30}
    short = Recording(rec.layout, frames, rec.timestamps[:60])
    emulator = DeviceEmulator(short, speed=None, loop=False)
    client = DSAClient(EmulatedTransport(emulator), rle=False, gap_timeout=0.3, stop_timeout=0.3, flush_max=0.3)
    client.open()
    client.start()
    got = []
    while (frame := client.read_frame(0.5)) is not None:
        got.append(frame)
        if len(got) == 60 - len(bad):
            break
    client.close()
    assert len(got) == 60 - len(bad)
    assert client.stats["frames_implausible"] == 3 and client.stats["decode_errors"] == 0
    assert all(int(f.values.max()) <= 4095 and f.values[dead] == 0 for f in got)
    kept = [i for i in range(60) if i not in bad]
    for f, i in zip(got, kept, strict=True):
        np.testing.assert_array_equal(f.values, frames[i])


def test_the_model_a_sleeper_replaced_serves_again_at_once(folders, caplog):
    models, state = folders
    write_model(models, "old.onnx", H.valid(bias_class=1, tag="old"), mtime=time.time() - 60)
    events: list[Event] = []
    daemon = _daemon(models, state, events)
    _start(daemon)
    write_model(models, "new.onnx", H.sleeper("nan_scores"))
    daemon.models.watcher.poll(require_stable=False)
    daemon._housekeeping(time.monotonic())
    assert Path(daemon.model.path).name == "new.onnx"
    _press(daemon, level=int(H.SLEEPER_PEAK))
    assert Path(daemon.model.path).name == "old.onnx" and events == []
    (line,) = [r.getMessage() for r in caplog.records if "taken out of service" in r.getMessage()]
    assert "scores contain NaN" in line and "old.onnx) serves again" in line
    _press(daemon, level=int(H.SLEEPER_PEAK), first=200)
    assert [e.cls for e in events] == ["push"]
    assert daemon.models.watcher.poll(require_stable=False) is None  # never reloaded while unchanged


# -- recordings -------------------------------------------------------------------------------------
R = pytest.importorskip("benchmarks.hostile_recordings")


@pytest.fixture(scope="module")
def hostile_recordings(tmp_path_factory):
    return R.write_all(tmp_path_factory.mktemp("hostile-recordings"), bomb_bytes=32 << 20)


def test_every_hostile_recording_is_one_line_naming_the_file(hostile_recordings, monkeypatch):
    import resource

    from firmware_io.recordings.importers import dsa

    monkeypatch.setattr(dsa, "MAX_XML_BYTES", 8 << 20)  # below this test's small bzip2 bomb

    from firmware_io.recordings.importers import import_any
    from firmware_io.recordings.recording import RecordingError

    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for name, path in hostile_recordings.items():
        with pytest.raises(RecordingError) as info:
            import_any(path)
        message = str(info.value)
        assert message.startswith(str(path)) and "\n" not in message and len(message) < 400, (name, message)
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    assert grown_mb < 30, f"reading hostile recordings grew the process by {grown_mb:.0f} MB"


@pytest.mark.parametrize(("command", "name"), [
    *[(c, n) for c in ("plot", "train") for n in ("deflate_bomb", "huge_shape", "deep_nesting", "bogus_layout")],
    ("emulate", "dsa_bzip2_bomb"), ("emulate", "deflate_bomb"),
])
def test_plot_train_emulate_end_with_one_line_and_exit_2(hostile_recordings, tmp_path, command, name):
    path = hostile_recordings[name]
    if command == "emulate":
        argv = ["emulate", "--pty", "--source", str(path), "--duration", "0.1"]
    elif command == "plot":
        argv = ["plot", str(path), "--out", str(tmp_path / "x.png")]
    else:
        data = tmp_path / "data"
        data.mkdir()
        (data / path.name).write_bytes(path.read_bytes())
        argv = ["train", "--data", str(data), "--out", str(tmp_path / "report")]
    done = subprocess.run([sys.executable, "-m", "runtime.cli", *argv], capture_output=True, text=True, cwd=ROOT,
                          timeout=120)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr[-2000:]
    assert lines[0].startswith(f"handover {command}: ") and path.name in lines[0]


def test_a_copy_that_pauses_is_not_picked_up_half_written(tmp_path, caplog):
    """An in-place copy that stops for longer than two polls looks complete to the size/mtime rule;
    a file that is not a whole model yet and was modified seconds ago is retried, not rejected."""
    caplog.set_level(logging.INFO, logger="handover.models")  # not left to what an earlier test configured
    data = H.valid()
    path = tmp_path / "copying.onnx"
    path.write_bytes(data[: len(data) // 2])
    path.chmod(0o644)
    watcher = ModelWatcher(tmp_path, loader=lambda p: load_model(p, warm_up=False), poll_interval=0.05)
    for _ in range(4):  # the copy pauses: the same half file on every poll
        assert watcher.poll() is None
    assert watcher.rejections == []
    assert len([r for r in caplog.records if "still being copied" in r.getMessage()]) == 1
    with path.open("ab") as fh:
        fh.write(data[len(data) // 2 :])
    watcher.poll()
    assert watcher.poll() is not None and watcher.rejections == []


@pytest.mark.parametrize("argv", [["--listen", "tcp://127.0.0.1:99999"], ["--pty", "--events", "99999999999"]])
def test_emulate_numbers_out_of_range_are_one_line(capsys, argv):
    from runtime.cli import main

    try:
        code = main(["emulate", *argv])
    except SystemExit as stop:  # an out-of-range number is argparse's one line
        code = stop.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("handover emulate: ") and "99999" in err and "\n" not in err


@pytest.mark.parametrize("url", ["tcp://10.0.0.2:13000?connect_timeout=nan", "tcp://10.0.0.2:13000?connect_timeout=inf",
                                 "sim://?speed=nan", "serial:///dev/ttyUSB0?baud=99999999999999999999",
                                 "sim://?events=99999999999999", "sim://?seed=-1"])
def test_numbers_in_the_device_url_are_finite_and_bounded(url):
    """The URL's options are numbers of the config too: NaN would turn a timeout off."""
    from runtime.config import ConfigError

    with pytest.raises(ConfigError) as info:
        config_from_dict({"device": {"url": url}})
    assert str(info.value).startswith("device.url: ") and "\n" not in str(info.value)


def test_only_event_lines_reach_stdout_even_from_c_code_or_a_library_print():
    code = ("import os, sys; from runtime.sinks import claim_stdout_for_events as c; s = c(); "
            "print('a library print'); os.write(1, b'a C++ log line\\n'); s.write('{\"class\":\"pull\"}\\n')")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=30)
    assert done.stdout == '{"class":"pull"}\n'
    assert "a library print" in done.stderr and "a C++ log line" in done.stderr


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_the_full_hostile_set_has_no_failures(tmp_path, capsys):
    """``./dev bench hostile``: every attack above at full size (3,000 mutated models, 100,000
    frames with 2-bit errors, a 2 GiB deflate bomb, ...) and the daemon as a real process while
    hostile models are dropped into its folder (stdout only JSON events, no traceback, exit 0);
    counted, results/hostile.md has a run."""
    from benchmarks.__main__ import main

    assert main(["hostile", "--out", str(tmp_path), "--quiet"]) == 0
    result = json.loads((tmp_path / "hostile.json").read_text())
    from benchmarks.hostile import summary

    print(json.dumps(summary(result)))
    assert result["hostile_failures"] == 0
    assert result["frames"]["delivered_over_12bit"] == 0 and result["daemon"]["non_json_stdout_lines"] == 0


def test_every_config_number_is_attacked_top_level_keys_too(tmp_path):
    """`./dev bench hostile` sets every ranged number (also `realtime_priority`, which has no section)
    to NaN, infinities, huge and negative values: each is refused in one line naming the key."""
    from benchmarks.hostile_io import BAD_NUMBERS, attack_config
    from runtime.config import RANGES

    res = attack_config(tmp_path)
    assert "realtime_priority" in RANGES and res["tried"] == len(RANGES) * len(BAD_NUMBERS)
    assert res["failures"] == 0, res
