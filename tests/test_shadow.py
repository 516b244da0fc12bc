"""A candidate model in shadow ([model] shadow; runtime/shadow.py): the same windows as the serving model,
off the hot thread, its own line type, compared in the health view, refused and quarantined like a model.

The daemon tests read the TCP emulator (the simulated hand, synthetic) with toy models (tests/tiny_models.py)
that decide a fixed class, so what is checked is the plumbing, not accuracy.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from runtime.config import ConfigError, config_from_dict
from runtime.daemon import Daemon
from runtime.quarantine import QuarantineStore, file_key
from runtime.shadow import QUEUE_WINDOWS, Shadow
from runtime.shadow_stats import MIN_WINDOWS, Comparison, verdict
from tests.ros2_helpers import TRIGGER, drain, run_until, udp_socket
from tests.tiny_models import CLASSES, tiny_model_bytes, write_model
from tests.waiting import wait_for

pytest.importorskip("onnx")
ROOT = Path(__file__).resolve().parents[1]
N_EVENTS = 6


def _bias(cls: str) -> tuple[float, ...]:
    return tuple(1.0 if c == cls else 0.0 for c in CLASSES)


def _folders(tmp_path: Path) -> tuple[Path, Path]:
    models, shadow = tmp_path / "models", tmp_path / "shadow"
    models.mkdir()
    shadow.mkdir()
    write_model(models, "serving.onnx", tiny_model_bytes(bias=_bias("pull")), mtime=time.time() - 100)
    return models, shadow


def _config(models: Path, shadow: Path, url: str, udp_port: int | None = None):
    return config_from_dict({
        "device": {"url": url, "reconnect_min_s": 0.05, "reconnect_max_s": 0.2},
        "model": {"folder": str(models), "shadow": str(shadow), "poll_interval_s": 0.05},
        "sinks": {"stdout": False, "udp": [f"127.0.0.1:{udp_port}"] if udp_port else []}, "trigger": TRIGGER})


def _on_emulator(cfg, until, hold_for_candidate: bool = True) -> Daemon:
    """The daemon on the TCP emulator (the simulated hand's session, once) until ``until(daemon)``; with
    ``hold_for_candidate`` the first event holds the stream until the candidate runs in shadow."""
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.frame_source import load_source
    from firmware_io.emulator.server import TcpEmulatorServer

    server = TcpEmulatorServer(DeviceEmulator(load_source("sim", seed=0, events=N_EVENTS), speed=None,
                                              loop=False)).start()

    def on_event(_event) -> None:
        if hold_for_candidate:
            wait_for(lambda: daemon.shadow.candidate is not None, 10)

    try:
        from dataclasses import replace

        daemon = Daemon(replace(cfg, device=replace(cfg.device, url=server.url)), on_event=on_event)
        run_until(daemon, until, timeout=30)
    finally:
        server.stop()
    return daemon


def _compared_all(d: Daemon) -> bool:
    c = d.shadow.comparison
    return d.health.device_faults >= 1 and c is not None and c.compared == d.health.decisions > 0


def test_shadow_lines_validate_and_health_compares_the_candidate(tmp_path):
    jsonschema = pytest.importorskip("jsonschema")
    models, shadow = _folders(tmp_path)
    write_model(shadow, "candidate.onnx", tiny_model_bytes(bias=_bias("push")))
    udp = udp_socket()
    daemon = _on_emulator(_config(models, shadow, "tcp://127.0.0.1:1", udp.getsockname()[1]), _compared_all)
    time.sleep(0.2)  # the last datagrams
    lines = [json.loads(line) for line in drain(udp)]
    udp.close()
    schema = json.loads((ROOT / "docs" / "events.schema.json").read_text())
    for line in lines:
        jsonschema.validate(line, schema)
    decisions = [x for x in lines if x["type"] == "decision"]
    shadows = [x for x in lines if x["type"] == "shadow"]
    assert decisions and {x["class"] for x in decisions} == {"pull"}
    assert len(shadows) == len(decisions)  # both report on every window here: one shadow line each
    serving_id, candidate_id = decisions[0]["model_id"], daemon.shadow.comparison.candidate_id
    for line in shadows:
        assert (line["class"], line["serving_class"], line["agrees"]) == ("push", "pull", False)
        assert line["model_id"] == candidate_id != serving_id == line["serving_model_id"]
    assert [x["frame_last"] for x in shadows] == [x["frame_last"] for x in decisions]  # the same windows
    documented = schema["$defs"]["shadow"]["properties"]
    doc = (ROOT / "docs" / "EVENTS.md").read_text()
    assert set(shadows[0]) == set(documented) and all(f"`{k}`" in doc for k in shadows[0])
    view = daemon.health.snapshot()["shadow"]
    n = len(decisions)
    assert view["windows_compared"] == n and view["agreement"] == 0.0 and view["confusion"] == {"pull": {"push": n}}
    assert view["false_events_on_serving_dormant"] == 0 and view["serving_events_on_candidate_dormant"] == 0
    assert view["latency_p50_us"] > 0 and view["windows_dropped"] == 0 and view["candidate_file"] == "candidate.onnx"
    assert f"not judged yet, {n} of {MIN_WINDOWS} windows compared, 0 of 20 events judged" in view["verdict"]


def test_a_broken_candidate_is_refused_and_serving_goes_on(tmp_path):
    models, shadow = _folders(tmp_path)
    data = tiny_model_bytes(bias=_bias("push"))
    write_model(shadow, "broken.onnx", data[: len(data) // 2], mtime=time.time() - 20)  # not being copied
    write_model(shadow, "wide.onnx", tiny_model_bytes(T=20, tag="w"), mtime=time.time() - 30)  # other windows
    daemon = _on_emulator(_config(models, shadow, "tcp://127.0.0.1:1"),
                          lambda d: d.health.device_faults >= 1 and d.shadow.rejected == 2, hold_for_candidate=False)
    assert daemon.health.events == daemon.health.decisions >= N_EVENTS - 1 and daemon.shadow.candidate is None
    errors = " | ".join(e["error"] for e in daemon.health.errors)
    assert "shadow model broken.onnx rejected" in errors
    assert "shadow model wide.onnx rejected: its window is 20, the serving model's 15: it cannot be fed" in errors
    assert daemon.health.snapshot()["shadow"]["models_rejected"] == 2


def test_shadow_folder_that_is_the_model_folder_is_refused_in_one_line(tmp_path):
    with pytest.raises(ConfigError, match=r"^model.shadow: .* is model.folder: a candidate dropped there would serve"):
        config_from_dict({"model": {"folder": str(tmp_path), "shadow": str(tmp_path / "." )}})
    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigError, match=r"^model.shadow: .* is not a folder"):
        config_from_dict({"model": {"folder": str(tmp_path), "shadow": str(tmp_path / "file")}})
    cfg = tmp_path / "h.toml"
    cfg.write_text(f'[model]\nfolder = "{tmp_path}"\nshadow = "{tmp_path}/"\n')
    out = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg), "--check"],
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert len([line for line in out.stderr.splitlines() if "model.shadow" in line]) == 1


# -- the shadow alone, with fake candidates -------------------------------------------------------------
class _Fake:
    """A candidate or serving model as the shadow sees it; ``run_trusted`` may block or fail."""

    def __init__(self, path: Path, label: int = 1, gate: threading.Event | None = None, fail: bool = False) -> None:
        self.path, self.model_id = path, "f" * 12
        self.meta = SimpleNamespace(T=15, n_channels=4, sample_rate_hz=32.0, pads=(1,), classes=CLASSES,
                                    n_classes=len(CLASSES), trigger={"kind": "onset", "back_frames": 3})
        self.label, self.gate, self.fail, self.runs = label, gate, fail, 0

    def run_trusted(self, window):
        self.runs += 1
        if self.gate is not None:
            self.gate.wait(10)
        if self.fail:
            return np.array([0]), np.array([[np.nan, 0, 0, 0]], np.float32)
        scores = np.zeros((1, len(CLASSES)), np.float32)
        scores[0, self.label] = 1
        return np.array([self.label]), scores


class _Ring:
    def window(self, T: int) -> np.ndarray:
        return np.zeros((1, T, 4), np.float32)


def _decision(serving: _Fake, number: int) -> SimpleNamespace:
    return SimpleNamespace(model=serving, frame=SimpleNamespace(number=number, timestamp_ms=31 * number),
                           label=0, report=0, first=number - 14)


def _shadow(tmp_path: Path, candidate: _Fake, serving: _Fake, clock=time.perf_counter, **kw) -> tuple[Shadow, list]:
    from runtime.health import Health

    folder = tmp_path / "shadow"
    folder.mkdir(exist_ok=True)
    write_model(folder, candidate.path.name, b"not read: the loader is a fake")
    candidate.path = folder / candidate.path.name
    cfg = config_from_dict({"model": {"folder": str(tmp_path / "models"), "shadow": str(folder),
                                      "poll_interval_s": 0.01, "decision_budget": 1.0}})
    lines: list = []
    shadow = Shadow(cfg, Health(), lambda p: candidate, lambda m: None, QuarantineStore(), lambda: serving,
                    lines.append, clock=clock, **kw)
    candidate.warm_up = lambda budget_fraction=None: None
    return shadow, lines


def test_a_slow_candidate_never_holds_the_hot_thread_back(tmp_path):
    """The candidate blocks; the hot thread's offers all return, the overflow is dropped and counted."""
    gate = threading.Event()
    serving = _Fake(Path("serving.onnx"), label=0)
    shadow, _ = _shadow(tmp_path, _Fake(Path("slow.onnx"), gate=gate), serving)
    shadow.start()
    try:
        assert wait_for(lambda: shadow.candidate is not None, 10)
        shadow.offer(_decision(serving, 100), _Ring())
        assert wait_for(lambda: shadow.candidate.runs == 1, 10)  # the shadow thread is stuck in that window
        extra = 3
        for i in range(QUEUE_WINDOWS + extra):
            shadow.offer(_decision(serving, 101 + i), _Ring())
        assert shadow.dropped == extra and shadow._queue.qsize() == QUEUE_WINDOWS
        gate.set()
        assert wait_for(lambda: shadow.comparison.compared == QUEUE_WINDOWS + 1, 10)
        assert shadow.counters()["shadow"]["windows_dropped"] == extra
    finally:
        gate.set()
        shadow.stop()


def test_serving_decisions_are_not_delayed_by_a_stuck_shadow(tmp_path):
    """The real hot path (Daemon.handle_frame) with a candidate that never answers: every serving decision is
    reported, and the windows the stuck shadow thread cannot take are dropped and counted."""
    from firmware_io.client import Frame
    from firmware_io.layout import SensorLayout
    from runtime.model import load_model

    models, shadow_folder = _folders(tmp_path)
    daemon = Daemon(config_from_dict({"model": {"folder": str(models), "shadow": str(shadow_folder)},
                                      "sinks": {"stdout": False}, "scene": {"mode": "continuous"}}))
    model = load_model(write_model(models, "d.onnx", tiny_model_bytes(classes=(*CLASSES, "dormant"),
                                                                      dormant_class="dormant", bias=(*_bias("pull"), 0.0))))
    layout = SensorLayout.sdh2()
    daemon.serve(model, layout)
    gate = threading.Event()
    stuck = _Fake(Path("stuck.onnx"), gate=gate)
    stuck.meta = model.meta
    values = np.zeros(layout.n_taxels, np.uint16)
    T, n = model.meta.T, model.meta.T + QUEUE_WINDOWS + 10
    daemon.shadow.start()
    daemon.shadow.candidate, daemon.shadow.comparison = stuck, Comparison("s" * 12, "stuck.onnx", 0)
    try:
        for i in range(n):
            daemon.handle_frame(Frame(i, 31 * i, time.perf_counter(), values))
            if i == T - 1:  # the first decision: the shadow thread takes its window and sticks in it
                assert wait_for(lambda: stuck.runs == 1, 10)
        decided = daemon.reporter.decisions
        assert decided == n - T + 1  # continuous mode: every frame from the T-th on is a decision
        assert daemon.shadow.dropped == decided - 1 - QUEUE_WINDOWS
    finally:
        gate.set()
        daemon.shadow.stop()


def test_a_candidate_that_breaks_the_contract_is_quarantined(tmp_path):
    serving = _Fake(Path("serving.onnx"), label=0)
    bad = _Fake(Path("nan.onnx"), fail=True)
    shadow, lines = _shadow(tmp_path, bad, serving)
    shadow.watch()
    shadow.step()  # the first poll takes the candidate
    assert shadow.candidate is bad
    shadow.offer(_decision(serving, 40), _Ring())
    shadow.step()
    assert shadow.candidate is None and shadow.quarantined == 1 and lines == []
    st = bad.path.stat()
    reason = shadow.quarantine.reason(file_key(bad.path, st.st_size, st.st_mtime_ns, st.st_ino))
    assert reason is not None and reason in shadow.health.last_error
    shadow._next_poll = 0.0
    shadow.step()  # the quarantined version is not loaded again
    assert shadow.candidate is None and "taken out" in shadow.health.last_error


def test_the_candidates_latency_is_its_own_decision_time_on_the_injected_clock(tmp_path):
    ticks = iter(np.arange(0.0, 100.0, 0.002))  # every reading of the clock 2 ms after the one before
    serving = _Fake(Path("serving.onnx"), label=0)
    shadow, lines = _shadow(tmp_path, _Fake(Path("c.onnx"), label=0), serving, clock=lambda: float(next(ticks)))
    shadow.watch()
    shadow.step()
    shadow.offer(_decision(serving, 40), _Ring())
    shadow.step()
    view = shadow.counters()["shadow"]
    assert view["latency_p50_us"] == 2000.0 and view["agreement"] == 1.0 and len(lines) == 1
    assert json.loads(lines[0].to_json())["agrees"] is True


@pytest.mark.parametrize(("agreed", "candidate_extra", "serving_extra", "word"), [
    (95, 2, 2, "passes"), (89, 0, 5, "fails"), (100, 3, 2, "fails")])
def test_the_shadow_rule(agreed, candidate_extra, serving_extra, word):
    c = Comparison("c" * 12, "c.onnx", 0)
    for i in range(100):
        same = i < agreed
        c.add("pull", False, "pull" if same else "push", False, 10.0)
    c.candidate_extra, c.serving_extra = candidate_extra, serving_extra
    line = verdict(c)
    assert f" {word} the shadow rule: agrees on {agreed / 100:.1%} of 100 windows" in line
    early = Comparison("c" * 12, "c.onnx", 0)
    early.add("pull", True, "pull", True, 1.0)
    assert f"not judged yet, 1 of {MIN_WINDOWS} windows compared, 0 of 20 events judged" in verdict(early)


def test_promotion_is_the_documented_file_move(tmp_path):
    """docs/GUIDE.md: touch the candidate, mv it into the model folder: it serves, and no candidate is left."""
    import os
    import shutil

    models, shadow = _folders(tmp_path)
    write_model(shadow, "candidate.onnx", tiny_model_bytes(bias=_bias("push")), mtime=time.time() - 200)
    events: list = []

    def on_event(event) -> None:
        events.append(event)
        if len(events) == 1:
            wait_for(lambda: daemon.shadow.candidate is not None, 10)
        if len(events) == 2:
            os.utime(shadow / "candidate.onnx")
            shutil.move(shadow / "candidate.onnx", models / "candidate.onnx")
            wait_for(lambda: daemon.models.watcher.pending is not None, 10)

    cfg = _config(models, shadow, f"sim://?events={N_EVENTS}&realtime=0&loop=0")
    daemon = Daemon(cfg, on_event=on_event)
    run_until(daemon, lambda d: d.health.device_faults >= 1 and d.shadow.candidate is None, timeout=30)
    assert [e.cls for e in events] == ["pull", "pull"] + ["push"] * (len(events) - 2) and len(events) > 2
    assert daemon.health.models_loaded == 2 and daemon.shadow.comparison.compared >= 1


def test_a_candidate_at_a_rate_the_stream_would_feed_as_it_comes_runs_beside_the_serving_model(tmp_path):
    """A rate estimated from other recordings (lab + field: 32.26 against 31.25 Hz) is refused only where the
    serving model itself would not be fed that stream frame by frame (runtime.frame_rate)."""
    serving, candidate = _Fake(Path("serving.onnx")), _Fake(Path("c.onnx"))
    serving.meta.sample_rate_hz, candidate.meta.sample_rate_hz = 31.250000000003443, 31.25000000001732
    shadow, _ = _shadow(tmp_path, candidate, serving)
    assert shadow.fit_problem(candidate) is None
    candidate.meta.sample_rate_hz = 32.258
    assert shadow.fit_problem(candidate) is None
    candidate.meta.sample_rate_hz = 70.0
    assert "its sample rate is 70.00 Hz, the serving model's 31.25 Hz" in shadow.fit_problem(candidate)


def test_a_candidate_cut_by_another_trigger_is_not_judged_on_the_serving_model_s_windows(tmp_path):
    """After an upgrade the serving model (cut at the trigger frame) and a new candidate (dated back) differ in
    where their windows start: a shadow verdict on the serving model's windows would judge cuts it never saw."""
    serving, candidate = _Fake(Path("serving.onnx")), _Fake(Path("c.onnx"))
    serving.meta.trigger = {"kind": "onset"}  # a model from before back_frames: served at the trigger frame
    shadow, _ = _shadow(tmp_path, candidate, serving)
    problem = shadow.fit_problem(candidate)
    assert "cut by another trigger: back_frames 3 (the serving model's 0)" in problem and "promote it" in problem
    serving.meta.trigger = {"kind": "onset", "back_frames": 3}
    assert shadow.fit_problem(candidate) is None


def test_sighup_starts_the_shadow_without_restarting_the_serving_watcher(tmp_path):
    from runtime.config import load_config

    models, shadow = _folders(tmp_path)
    write_model(shadow, "candidate.onnx", tiny_model_bytes(bias=_bias("push")))
    path = tmp_path / "handover.toml"
    base = f'[device]\nurl = "sim://"\n[sinks]\nstdout = false\n[model]\nfolder = "{models}"\npoll_interval_s = 0.05\n'
    path.write_text(base)
    daemon = Daemon(load_config(path))
    daemon.models.start()
    serving_watcher = daemon.models.watcher
    try:
        path.write_text(base + f'shadow = "{shadow}"\n')
        daemon.reload()
        assert daemon.cfg.model.shadow == str(shadow) and daemon.models.watcher is serving_watcher
        assert wait_for(lambda: daemon.shadow.candidate is not None, 10)
        path.write_text(base)
        daemon.reload()
        assert daemon.shadow.candidate is None and daemon.shadow.counters() == {}
    finally:
        daemon.shadow.stop()
        daemon.models.stop()


def test_check_names_a_missing_shadow_folder_in_one_line(tmp_path):
    models, _ = _folders(tmp_path)
    cfg = tmp_path / "h.toml"
    cfg.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\nshadow = "{tmp_path}/nowhere"\n')
    out = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg), "--check"],
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1].endswith(f"model.shadow {tmp_path}/nowhere does not exist: create it "
                                                        f"(mkdir -p {tmp_path}/nowhere) or fix the path in {cfg}")


def test_the_robots_outcome_judges_both_models_on_the_last_event(tmp_path):
    serving = _Fake(Path("serving.onnx"), label=0)  # pull, reported
    shadow, _ = _shadow(tmp_path, _Fake(Path("c.onnx"), label=1), serving)  # the candidate says push
    shadow.watch()
    shadow.step()
    for i in range(3):
        shadow.offer(_decision(serving, 40 + 50 * i), _Ring())
        shadow.step()

    def judged() -> tuple[int, int, int]:
        shadow.step()
        view = shadow.counters()["shadow"]
        return view["events_with_outcome"], view["serving_right"], view["candidate_right"]

    shadow.outcome("taken")  # the person took it: a pull, as served
    assert judged() == (1, 1, 0)
    shadow.outcome("push")  # a person's label on the same event replaces the robot's word
    assert judged() == (1, 0, 1)
    shadow.outcome("dropped")  # tells neither
    assert judged() == (1, 0, 1) and "1 of 20 events judged by the robot's outcome" in shadow.counters()["shadow"]["verdict"]


def test_outcomes_reach_the_shadow_only_through_field_capture(tmp_path):
    models, shadow_folder = _folders(tmp_path)
    daemon = Daemon(_config(models, shadow_folder, "sim://"))
    heard: list[str] = []
    daemon.shadow.outcome = heard.append
    daemon.robot.outcome("taken", "control")  # capture off: ignored (one warning), not judged
    daemon.robot.capture = SimpleNamespace(outcome=lambda word, source: word != "bogus")
    daemon.robot.outcome("bogus", "control")  # refused by capture
    daemon.robot.outcome("kept", "control")
    assert heard == ["kept"]


def test_the_shadow_rule_with_outcomes():
    c = Comparison("c" * 12, "c.onnx", 0)
    for i in range(100):
        c.add("pull", True, "pull" if i < 50 else "push", True, 10.0)  # agrees on half only
    for frame in range(25):
        c.judge(frame, serving_right=frame < 10, candidate_right=frame < 20)
    assert " passes the shadow rule: right on 20 of 25 events the robot's outcome judges, the serving model on 10" \
        in verdict(c)
    c.candidate_extra = 1
    assert " fails the shadow rule" in verdict(c)
