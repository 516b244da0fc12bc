"""``handover dump`` summaries: no phantom timeout at the end of --seconds, and an honest
receive rate for a source that sends as fast as possible (simulated hand, synthetic)."""

from __future__ import annotations

import json

from runtime.cli import main


def _summary(capsys, *argv: str) -> dict:
    assert main(["dump", *argv, "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert lines[0]["type"] == "layout" and lines[-1]["type"] == "summary"
    return lines[-1]


def test_the_end_of_seconds_is_not_a_timeout(capsys):
    summary = _summary(capsys, "sim://", "--seconds", "0.5")
    assert summary["frames"] >= 10
    assert summary["stats"]["timeouts"] == 0
    assert 25 < summary["rate_hz"] < 40 and 25 < summary["device_rate_hz"] < 40  # paced at ~32 Hz


def test_as_fast_as_possible_says_so_instead_of_a_bare_null(capsys):
    summary = _summary(capsys, "sim://?realtime=0", "--frames", "30")
    assert summary["frames"] == 30 and summary["stats"]["timeouts"] == 0
    assert 25 < summary["device_rate_hz"] < 40  # the device clock still tells the frame period
    if summary["rate_hz"] is None:  # every frame came out of one read: one receive time
        assert summary["rate_note"].startswith("n/a (as fast as possible")
    assert main(["dump", "sim://?realtime=0", "--frames", "30"]) == 0
    last = capsys.readouterr().out.splitlines()[-1]
    assert "received at" in last and "received at n/a (device" not in last and "timeouts 0" in last


def test_the_preview_starts_at_the_first_contact_and_says_so(capsys):
    """issue 15: the simulated hand's session starts idle; fifty rows of zeros showed nothing."""
    assert main(["dump", "sim://?realtime=0", "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    notes = [x["text"] for x in lines if x["type"] == "note"]
    frames = [x for x in lines if x["type"] == "frame"]
    summary = lines[-1]
    assert len(frames) == 50 and frames[0]["max"] > 0
    assert summary["idle_frames_skipped"] > 0 and f"skipped {summary['idle_frames_skipped']} frames" in notes[-1]
    assert frames[0]["number"] == summary["idle_frames_skipped"]  # nothing lost, only not shown
    every = _summary(capsys, "sim://?realtime=0", "--all-frames")
    assert every["idle_frames_skipped"] == 0 and every["frames"] == 50
