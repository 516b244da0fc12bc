"""The status file: atomic JSON, and an unwritable file that never floods the journal."""

from __future__ import annotations

import json
import logging

from runtime.health import Health, StatusFile


def test_status_file_is_written_atomically(tmp_path):
    path = tmp_path / "status.json"
    assert StatusFile(path).write(Health().snapshot())
    assert json.loads(path.read_text())["device_state"] == "starting"
    assert [p.name for p in tmp_path.iterdir()] == ["status.json"]  # no temp file left behind


def test_an_unwritable_status_file_is_logged_rarely_with_a_count(tmp_path, caplog):
    folder = tmp_path / "gone"
    status = StatusFile(folder / "status.json", log_every_s=300.0)
    data = Health().snapshot()
    with caplog.at_level(logging.INFO, logger="handover.health"):
        for second in range(600):  # ten minutes of the daemon's once-a-second writes
            assert not status.write(data, now=float(second))
        warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert len(warnings) == 2, warnings  # the first failure, then one after 5 minutes
        assert "gone/status.json" in warnings[0] and "since the last message" not in warnings[0]
        assert "(300 failed writes since the last message)" in warnings[1]
        assert status.failures == 600
        folder.mkdir()
        assert status.write(data, now=600.0)
    assert "written again (600 failed writes in total)" in caplog.records[-1].getMessage()


def test_a_repeated_error_is_counted_so_the_history_keeps_what_came_before():
    health = Health()
    health.report_error("model folder /m: missing", "model")
    for _ in range(500):  # a device refusing every retry of a long outage
        health.report_error("tcp://h:1: cannot connect: Connection refused", "device")
    health.report_error("tcp://h:1: no reply within 10 s", "device")
    errors = health.snapshot()["recent_errors"]
    assert [e["error"] for e in errors] == ["model folder /m: missing", "tcp://h:1: cannot connect: Connection refused",
                                            "tcp://h:1: no reply within 10 s"]
    assert errors[1]["repeats"] == 500 and errors[1]["last_at"] >= errors[1]["at"]
    assert "repeats" not in errors[2] and health.last_error == "tcp://h:1: no reply within 10 s"


def test_each_part_keeps_its_counters_and_the_health_view_composes_them():
    """Health was written by five parts (the daemon, the link copying the client's stats, the frame clock,
    the model slot, the reporter); now each keeps its own and the view composes them, keys unchanged."""
    import re
    from pathlib import Path

    from runtime.health import SNAPSHOT

    health = Health()
    health.parts = [lambda: {"events": 3, "device_state": "streaming"}, lambda: {"crc_errors": 2}]
    snapshot = health.snapshot()
    assert list(snapshot) == list(SNAPSHOT) and (snapshot["events"], snapshot["crc_errors"]) == (3, 2)
    assert health.events == 3 and health.decisions == 0 and "streaming; 0.0 frames/s; 3 events" in health.status_line()
    own = {"frame_errors", "instance", "last_error", "last_error_at"}
    written = re.compile(r"\b(?:health|h)\.(" + "|".join(sorted(set(SNAPSHOT) - own)) + r")\s*(?:\+?=)(?!=)")
    root = Path(__file__).resolve().parents[1] / "runtime"
    assert {p.name: written.findall(p.read_text()) for p in root.glob("*.py") if written.search(p.read_text())} == {}
