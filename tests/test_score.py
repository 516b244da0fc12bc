"""``handover emulate --script-out`` + ``handover score``: a captured event stream scored against the
scripted session gives the demo's counts. Real processes: the emulator on loopback TCP, the daemon
writing its event lines to stdout, the score command reading them. Data: the simulated hand
(synthetic); the model is a toy that always says pull (tests/tiny_models.py)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from firmware_io.emulator.script_file import ScriptFileError, read_script, session_script, write_script
from firmware_io.sim import demo_script, simulate_session
from tests.memory import PEAK_MB
from tests.ros2_helpers import TRIGGER
from tests.tiny_models import tiny_model_bytes, write_model

ROOT = Path(__file__).resolve().parents[1]
EVENTS, SEED = 6, 3


def _handover(*argv: str, **kw) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT), XDG_RUNTIME_DIR=kw.pop("run_dir"))
    return subprocess.Popen([sys.executable, "-m", "runtime.cli", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT, **kw)


def _demo_counts(lines: list[str], session_ms: int) -> dict:
    """The demo's own path for the same lines: its EventLog maps each event to the session's frames
    and session_outcomes scores them (trainer/commands/demo_cli.py)."""
    from trainer.commands.demo_cli import EventLog
    from trainer.session_score import outcome_summary
    from trainer.streams_eval import session_outcomes

    session = simulate_session(demo_script(EVENTS, seed=SEED), seed=SEED)
    log = EventLog(SimpleNamespace(quiet=True, json=False), session, demo_script(EVENTS, seed=SEED),
                   SimpleNamespace(session_clock_ms=session_ms))
    for line in lines:
        obj = json.loads(line)
        if obj.get("type") == "decision":
            log.on_event(SimpleNamespace(device_time_ms=obj["device_time_ms"], cls=obj["class"],
                                         latency_us=obj["latency_us"]))
    return outcome_summary(session_outcomes(log.decisions, session.trials))


def test_score_of_an_emulated_session_equals_the_demos_summary(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes(), mtime=time.time() - 10)
    script = tmp_path / "script.jsonl"
    emu = _handover("emulate", "--listen", "tcp://127.0.0.1:0", "--events", str(EVENTS), "--seed", str(SEED),
                    "--speed", "4", "--no-loop", "--clock-start", "5000", "--script-out", str(script),
                    run_dir=str(run_dir))
    daemon = None
    try:
        head = emu.stdout.readline()
        n_frames = int(head.split(" frames")[0].rsplit(" ", 1)[1])
        url = emu.stdout.readline().split()[-1]
        assert url.startswith("tcp://"), url
        trigger = "".join(f"{k} = {v}\n" for k, v in TRIGGER.items())
        cfg = tmp_path / "handover.toml"
        cfg.write_text(f'health_file = "{tmp_path / "status.json"}"\n[device]\nurl = "{url}"\nstall_timeout_s = 5.0\n'
                       f'[model]\nfolder = "{models}"\n[trigger]\n{trigger}[sinks]\nstdout = true\n')
        daemon = _handover("run", "--config", str(cfg), run_dir=str(run_dir))
        started = emu.stdout.readline()  # once the daemon asks for frames: the session's first frame's device time
        assert started.startswith("session started at device time"), started
        session_ms = int(started.split("device time ")[1].split()[0])
        assert session_ms > 5000  # the clock ran from power-on before the daemon came
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            try:
                if json.loads((tmp_path / "status.json").read_text())["frames_received"] >= n_frames:
                    break
            except (OSError, ValueError, KeyError):
                pass
            time.sleep(0.2)
        else:
            raise AssertionError("the daemon did not read the whole session")
        time.sleep(1.0)
    finally:
        for proc in (daemon, emu):
            if proc is not None:
                proc.send_signal(signal.SIGTERM)
        out = daemon.communicate(timeout=30)[0] if daemon is not None else ""
        emu_out = emu.communicate(timeout=30)[0]
    assert f"session over: all {n_frames} frames sent (--no-loop); stop the daemon; then handover score" in emu_out
    assert read_script(script).ended  # written again once the whole session was sent: no event is left unplayed
    events = tmp_path / "events.jsonl"
    events.write_text(out)
    lines = [line for line in out.splitlines() if line.startswith("{")]
    assert sum('"decision"' in line for line in lines) >= 3
    scored = subprocess.run([sys.executable, "-m", "runtime.cli", "score", str(events), str(script), "--json"],
                            capture_output=True, text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                            timeout=60)
    assert scored.returncode == 0, scored.stderr
    got = json.loads(scored.stdout)
    want = _demo_counts(lines, session_ms)
    keys = ("events_expected", "events_detected", "events_correct", "events_missed", "false_events", "repeat_events",
            "missed_events", "wrong_events", "per_class_correct", "report_minus_onset_frames")
    assert {k: got[k] for k in keys} == {k: want[k] for k in keys}
    assert got["events_expected"] == EVENTS and got["events_detected"] >= 3
    assert 0 < got["events_correct"] < got["events_detected"]  # the toy says pull to everything: some wrong
    text = subprocess.run([sys.executable, "-m", "runtime.cli", "score", str(events), str(script)],
                          capture_output=True, text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                          timeout=60).stdout
    assert f"  events: {EVENTS} scripted, {got['events_detected']} detected" in text and "  wrong: #" in text
    # --instance: only that daemon's lines (the config set none: <host>:<device>)
    mine = json.loads(lines[0])["instance"]
    for instance, detected in ((mine, got["events_detected"]), ("another-hand", 0)):
        only = subprocess.run([sys.executable, "-m", "runtime.cli", "score", str(events), str(script), "--json",
                               "--instance", instance], capture_output=True, text=True, cwd=ROOT,
                              env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=60)
        assert json.loads(only.stdout)["events_detected"] == detected, only.stderr


def test_the_script_names_each_event_and_maps_device_time_to_frames(tmp_path):
    rec = simulate_session(demo_script(4, seed=1), seed=1)
    path = tmp_path / "s.jsonl"
    assert write_script(path, rec, clock_start_ms=1000, loop=True, source="sim") == 4
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert [r["action"] for r in rows[1:]] == [t.action for t in rec.trials]
    assert all({"onset_frame", "subject", "first_frame", "last_frame"} <= set(r) for r in rows[1:])
    script = read_script(path)
    assert script.trials == rec.trials and script.clock_start_ms == 1000
    ms = session_script(rec).frame_ms
    assert script.frame_of(1000 + int(ms[37])) == (0, 37)
    assert script.frame_of(1000 + script.loop_ms + int(ms[37])) == (1, 37)  # the second pass of a looping session
    path.write_text('{"type": "decision"}\n')
    with pytest.raises(ScriptFileError, match="no script header"):
        read_script(path)


def _score(events: Path, script: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "runtime.cli", "score", str(events), str(script)],
                          capture_output=True, text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                          timeout=120)


def test_garbled_numbers_in_a_script_or_the_events_are_one_line_and_never_hang(tmp_path):
    """Numbers JSON allows but no emulator writes (1e400 is infinite, 10^30 overflows an int64, a loop
    of 1 ms, a device time of 10^18 ms on a looping script) were tracebacks or hours of work."""
    rec = simulate_session(demo_script(2, seed=1), seed=1)
    good = tmp_path / "good.script"
    write_script(good, rec, loop=True, source="sim")
    head, *rest = good.read_text().splitlines()
    ms = int(session_script(rec).frame_ms[40])
    events = tmp_path / "events.jsonl"
    events.write_text(json.dumps({"type": "decision", "class": "pull", "device_time_ms": ms}) + "\n")
    assert _score(events, good).returncode == 0
    meta = json.loads(head)
    garbled = {"clock_inf": head.replace(f'"clock_start_ms": {meta["clock_start_ms"]}', '"clock_start_ms": 1e400'),
               "frame_huge": head.replace('"frame_ms": [0,', f'"frame_ms": [{10 ** 30},'),
               "loop_1ms": json.dumps({**meta, "loop_ms": 1}), "loop_negative": json.dumps({**meta, "loop_ms": -5})}
    for name, text in garbled.items():
        assert text != head, name
        path = tmp_path / f"{name}.script"
        path.write_text("\n".join([text, *rest]) + "\n")
        done = _score(events, path)
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1 and "write it again with handover emulate" in lines[0], \
            (name, done.stderr)
    trial = json.loads(rest[0])
    for name, line in {"time_inf": '{"type": "decision", "class": "pull", "device_time_ms": 1e400}',
                       "trial_inf": None}.items():
        if line is None:
            bad_script = tmp_path / "trial_inf.script"
            bad_script.write_text("\n".join([head, json.dumps(trial).replace(
                f'"first_frame": {trial["first_frame"]}', '"first_frame": 1e400'), *rest[1:]]) + "\n")
            done = _score(events, bad_script)
            assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
            continue
        bad = tmp_path / f"{name}.jsonl"
        bad.write_text(events.read_text() + line + "\n")
        done = _score(bad, good)
        assert done.returncode == 0 and "1 lines were not event lines" in done.stdout and not done.stderr, done.stderr
    far = tmp_path / "far.jsonl"
    far.write_text(events.read_text() + json.dumps({"type": "decision", "class": "pull", "device_time_ms": 10 ** 18}) + "\n")
    done = _score(far, good)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and "passes of the script" in lines[0], done.stderr


def test_a_script_out_naming_a_folder_leaves_no_temporary_file(tmp_path):
    rec = simulate_session(demo_script(2, seed=1), seed=1)
    folder = tmp_path / "scripts"
    folder.mkdir()
    with pytest.raises(IsADirectoryError):
        write_script(folder, rec)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scripts"]


def test_a_capture_that_ends_before_the_script_counts_the_rest_as_not_played(tmp_path, capsys):
    """Scoring while the session still plays: events after the last decision are not played yet (one
    line says where the capture ends), not missed; once the emulator wrote the script again with the
    whole session sent (``ended``), the same events are missed."""
    from runtime.cli import main as handover

    rec = simulate_session(demo_script(4, seed=1), seed=1)
    first = rec.trials[0]
    ms = session_script(rec).frame_ms
    events = tmp_path / "events.jsonl"
    events.write_text(json.dumps({"type": "decision", "class": first.action,
                                  "device_time_ms": int(ms[first.extra["onset"] + 10])}) + "\n")
    playing, over = tmp_path / "playing.script", tmp_path / "over.script"
    write_script(playing, rec, loop=False, source="sim")
    write_script(over, rec, loop=False, source="sim", ended=True)

    assert handover(["score", str(events), str(playing), "--json"]) == 0
    captured = capsys.readouterr()
    got = json.loads(captured.out)
    assert (got["events_expected"], got["events_correct"], got["events_missed"], got["events_not_played"]) == (1, 1, 0, 3)
    line = captured.err.strip()
    assert len(captured.err.splitlines()) == 1 and line.startswith(f"handover score: {events} ends at frame "
                                                                   f"{first.extra['onset'] + 10} (its last decision)")
    assert f"before the script's last event at frame {rec.trials[-1].extra['onset']}: 3 scripted events" in line
    assert handover(["score", str(events), str(playing)]) == 0
    assert "3 scripted events after it are counted as not played yet, not missed" in capsys.readouterr().out

    assert handover(["score", str(events), str(over), "--json"]) == 0
    captured = capsys.readouterr()
    got = json.loads(captured.out)
    assert (got["events_expected"], got["events_missed"], got["events_not_played"]) == (4, 3, 0) and not captured.err


def _measured_score(events: Path | str, script: Path | str) -> tuple[subprocess.CompletedProcess, dict]:
    """``handover score`` in a child that reports its own peak memory (MB) and CPU seconds on its last stdout line
    (CPU, not wall-clock: the bound is the work done, and a machine busy with other work must not fail it)."""
    code = ("import json, sys, time\nfrom runtime.cli import main\nt = time.process_time()\n"
            "rc = main(['score', sys.argv[1], sys.argv[2]])\n"
            "print(json.dumps({'rc': rc, 's': time.process_time() - t,"
            " 'mb': " + PEAK_MB + "}))")
    done = subprocess.run([sys.executable, "-c", code, str(events), str(script)], capture_output=True, text=True,
                          cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=60)
    return done, json.loads(done.stdout.strip().splitlines()[-1]) if done.returncode == 0 else {}


def _script_lines(head: dict, events: list[dict]) -> str:
    return "\n".join(json.dumps(r, separators=(",", ":")) for r in [head, *events]) + "\n"


def test_hostile_scripts_are_refused_in_one_line_quickly_and_in_little_memory(tmp_path):
    """What write_script never writes, and files that ate the machine: 500 events on a 500 ms loop and two
    decisions 99,998 ms apart (a 1 ms loop was 50 million scripted events, 2.8 GB), 101,091 events under the
    size cap (11 s, 645 MB), 100,000 nested brackets (RecursionError) in the script or the events, /dev/zero
    (MemoryError), frames that descend, go negative, are fractional or past the end, overlapping or repeated
    events, a 1 MB name or one with an ESC (printed raw); the script as the events (a 0-decision scorecard)."""
    head = {"type": "script", "protocol": 1, "started": True, "ended": False, "source": "", "synthetic": True,
            "clock_start_ms": 0, "loop_ms": 1, "frames": 1, "frame_ms": [0]}
    one = {"type": "scripted", "event": 1, "onset_frame": 0, "action": "pull", "subject": "s1", "object": "ball",
           "pose": "up", "first_frame": 0, "last_frame": 0, "time_s": None}
    events = tmp_path / "events.jsonl"
    events.write_text("".join(json.dumps({"type": "decision", "class": "pull", "device_time_ms": t}) + "\n"
                              for t in (0, 99_998)))
    wide = {**head, "loop_ms": None, "frames": 3, "frame_ms": [0, 31, 62]}
    many = {**head, "loop_ms": 500, "frames": 500, "frame_ms": list(range(500))}
    spans = {**head, "loop_ms": None, "frames": 853, "frame_ms": list(range(0, 853 * 32, 32))}
    cases = {
        "bomb": (_script_lines(many, [{**one, "event": k, "first_frame": k - 1, "onset_frame": k - 1,
                                       "last_frame": k - 1} for k in range(1, 501)]), "passes of the script"),
        "events_bomb": (_script_lines(spans, [{**one, "event": k, "last_frame": 852} for k in range(1, 101_092)]),
                        "101091 scripted events, more than any session handover scripts"),
        "overlapping": (_script_lines(wide, [{**one, "last_frame": 1}, {**one, "event": 2, "first_frame": 1, "last_frame": 2}]),
                        "scripted event 2 (frames 1..2) starts before event 1 ends"),
        "duplicate": (_script_lines(wide, [one, {**one, "first_frame": 2, "last_frame": 2}]),
                      "scripted event 1 appears twice"),
        "escape_in_name": (_script_lines(wide, [{**one, "action": "pu\u001b[2Jll\nX"}]),
                           r"action must be a name of 1 to 64 printable characters, got 'pu\x1b[2Jll\nX'"),
        "nested": ("[" * 100_000 + "]" * 100_000 + "\n", "not JSON lines"),
        "descending": (_script_lines({**wide, "frame_ms": [0, 62, 31]}, [one]), "goes back in time"),
        "first_after_last": (_script_lines(wide, [{**one, "first_frame": 2, "last_frame": 1}]), "after its last"),
        "negative": (_script_lines(wide, [{**one, "first_frame": -1}]), "whole frames of the session"),
        "onset_past_end": (_script_lines(wide, [{**one, "onset_frame": 3}]), "whole frames of the session"),
        "fractional": (_script_lines(wide, [{**one, "last_frame": 1.5}]), "whole frames of the session"),
        "huge_name": (_script_lines(wide, [{**one, "action": "x" * (1 << 20)}]), "action must be a name"),
    }
    assert len(cases["events_bomb"][0]) < 16 << 20  # under the size cap, as the attacker's was
    for name, (text, says) in {**cases, "dev_zero": (None, "not a regular file")}.items():
        script = "/dev/zero" if text is None else tmp_path / f"{name}.script"
        if text is not None:
            script.write_text(text)
        done, took = _measured_score(events, script)
        lines = done.stderr.strip().splitlines()
        assert took["rc"] == 2 and len(lines) == 1 and says in lines[0] and len(lines[0]) < 400, (name, done.stderr[-500:])
        assert took["s"] < 5 and took["mb"] < 500, (name, took)
    good = tmp_path / "first_after_last.script"
    good.write_text(cases["descending"][0].replace("[0,62,31]", "[0,31,62]"))
    done, took = _measured_score("/dev/zero", good)  # as the events: endless, without a line end
    lines = done.stderr.strip().splitlines()
    assert took["rc"] == 2 and len(lines) == 1 and "MiB of event lines" in lines[0], done.stderr[-300:]
    assert took["s"] < 5 and took["mb"] < 500, took
    decision = json.dumps({"type": "decision", "class": "pull", "device_time_ms": 31}) + "\n"
    given = {"nested": ("[" * 100_000 + "]" * 100_000 + "\n", "none of its 1 lines is an event line"),
             "script": (good.read_text(), "a script (what handover emulate --script-out writes), not event lines"),
             "too_many": (decision * 50_001, "more than 50000 lines"),
             "one_huge_line": ("[" + "{}," * (1 << 20) + "{}]\n", "none of its 1 lines is an event line")}
    for name, (text, says) in given.items():
        path = tmp_path / f"{name}.jsonl"
        path.write_text(text)
        done, took = _measured_score(path, good)
        lines = done.stderr.strip().splitlines()
        assert took["rc"] == 2 and len(lines) == 1 and says in lines[0], (name, done.stderr[-300:])
        assert took["s"] < 5 and took["mb"] < 500 and not done.stdout.strip().splitlines()[:-1], (name, took)


def test_a_log_given_as_the_events_is_said_not_scored(tmp_path):
    """The daemon's log instead of its stdout printed a 0-of-N scorecard with exit 0."""
    rec = simulate_session(demo_script(2, seed=1), seed=1)
    script = tmp_path / "s.script"
    write_script(script, rec, source="sim")
    log = tmp_path / "daemon.log"
    log.write_text("2026-01-01 12:00:00 handover: connected to tcp://127.0.0.1:1\nframes at 31.2 Hz\n")
    done = _score(log, script)
    assert done.returncode == 2 and "none of its 2 lines is an event line" in done.stderr and not done.stdout, done
    huge = tmp_path / "huge_class.jsonl"  # a class name the summary would print verbatim
    t = int(session_script(rec).frame_ms[rec.trials[0].extra["onset"] + 5])
    huge.write_text("".join(json.dumps({"type": "decision", "class": c, "device_time_ms": t}) + "\n"
                            for c in ("x" * (1 << 20), rec.trials[0].action)))
    done = _score(huge, script)
    assert done.returncode == 0 and len(done.stdout) < 2000 and "1 lines were not event lines" in done.stdout, done


def test_the_guides_sample_summary_is_what_the_program_prints_for_the_stored_session():
    """docs/GUIDE.md shows the demo's summary lines for the session in results/streams.json, for people
    (``per class correct: bump 9/10, ...``, not a Python dict)."""
    from trainer.session_score import outcome_summary, summary_lines

    blocks = (ROOT / "docs" / "GUIDE.md").read_text().split("```")[1::2]
    sample = next(b for b in blocks if "per class correct:" in b).strip("\n").splitlines()
    demo = json.loads((ROOT / "results" / "streams.json").read_text())["demo"]
    assert sample == summary_lines(outcome_summary(demo[demo["mode"]]), demo["mode"])
    assert "  per class correct: bump 9/10, hold 10/10, pull 10/10, push 10/10" in sample
