"""``./dev bench field``'s own arithmetic: the truth the scripted robot says, and how reports are scored
against the session (the runs themselves are the benchmark, not a unit test)."""

from __future__ import annotations

from benchmarks.field import first_reports, missing_parts, scored
from benchmarks.field_run import Day, config_text, truth_of
from firmware_io.emulator.script_file import session_script
from firmware_io.sim import demo_script, simulate_session


def test_the_robot_says_the_scripted_class_inside_an_event_and_dormant_outside():
    rec = simulate_session(demo_script(4, seed=7), seed=7)
    script = session_script(rec, clock_start_ms=5000)
    t = rec.trials[1]
    inside = 5000 + int(script.frame_ms[(t.first + t.last) // 2])
    assert truth_of(script, inside) == t.action
    assert truth_of(script, 5000 + int(script.frame_ms[rec.trials[0].first - 1])) == "dormant"
    day = Day([], script, {})
    at = [5000 + int(script.frame_ms[tr.last]) for tr in rec.trials]
    lines = [{"class": rec.trials[0].action, "device_time_ms": at[0]},  # right
             {"class": rec.trials[0].action, "device_time_ms": at[0]},  # a repeat: only the first counts
             {"class": "wave", "device_time_ms": at[1]},  # wrong
             {"class": "pull", "device_time_ms": 5000 + int(script.frame_ms[rec.trials[0].first - 1])}]  # outside
    firsts, outside = first_reports(lines, day)
    assert scored(firsts, outside, day) == {"events": 4, "right": 1, "wrong": 1, "missed": 2, "false_events": 1,
                                            "right_fraction": 0.25}
    shadow = [{**line, "reported": k != 0} for k, line in enumerate(lines)]  # the candidate kept quiet on one
    assert first_reports(shadow, day, reported_only=True) == ({0: rec.trials[0].action, 1: "wave"}, 1)


def test_the_days_config_names_shadow_and_capture_only_when_given(tmp_path):
    plain = config_text("tcp://127.0.0.1:1", tmp_path, tmp_path / "m", None, None, 60)
    assert "shadow" not in plain and "[capture]" not in plain and "stdout = true" in plain
    full = config_text("tcp://127.0.0.1:1", tmp_path, tmp_path / "m", tmp_path / "s", tmp_path / "f", 60)
    assert f'shadow = "{tmp_path / "s"}"' in full and "idle_every_s = 60" in full
    assert isinstance(missing_parts(), list)
