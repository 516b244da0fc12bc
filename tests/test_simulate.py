"""The simulated hand: determinism, frame format, action signatures, protocol and session."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_io.layout import SensorLayout
from firmware_io.recordings.recording import ACTIONS, Recording
from firmware_io.sim import (
    OBJECTS,
    POSES,
    ScriptedEvent,
    demo_script,
    simulate_protocol,
    simulate_session,
    write_protocol,
)

LAYOUT = SensorLayout.sdh2()
DISTAL = LAYOUT.columns("distal")
PROXIMAL = LAYOUT.columns("proximal")


@pytest.fixture(scope="module")
def small() -> list[Recording]:
    """2 subjects x 2 runs x 3 poses x 3 objects x 4 actions = 144 synthetic trials."""
    return simulate_protocol(seed=3, n_subjects=2, runs=2)


def test_same_seed_gives_identical_bytes(tmp_path):
    a = write_protocol(tmp_path / "a", seed=7, n_subjects=1, runs=1, objects=("ball",))
    b = write_protocol(tmp_path / "b", seed=7, n_subjects=1, runs=1, objects=("ball",))
    assert [p.name for p in a] == ["subject_s1.hrec"]
    assert a[0].read_bytes() == b[0].read_bytes()


def test_different_seed_gives_different_frames():
    a = simulate_protocol(seed=1, n_subjects=1, runs=1, objects=("ball",))[0]
    b = simulate_protocol(seed=2, n_subjects=1, runs=1, objects=("ball",))[0]
    assert not np.array_equal(a.frames, b.frames)


def test_adding_trials_does_not_change_existing_ones():
    one = simulate_protocol(seed=5, n_subjects=1, runs=1, objects=("plank",), actions=("push",))[0]
    more = simulate_protocol(seed=5, n_subjects=2, runs=2, objects=("ball", "plank"), actions=("pull", "push"))[0]
    key = lambda t: (t.pose, t.object, t.action, t.run)  # noqa: E731
    index = {key(t): t for t in more.trials}
    for tr in one.trials:
        other = index[key(tr)]
        np.testing.assert_array_equal(one.trial_frames(tr)[0], more.trial_frames(other)[0])


def test_frame_format(small):
    mask = LAYOUT.static_mask()
    for rec in small:
        assert rec.frames.dtype == np.uint16 and rec.frames.shape[1] == 486
        assert rec.frames.max() <= 4095
        assert not rec.frames[:, ~mask].any(), "static-mask taxels must read 0"
        assert np.all(np.diff(rec.timestamps) > 0)
        assert rec.meta["synthetic"] is True
        assert 0.025 < rec.sample_interval() < 0.04


def test_protocol_counts_and_balance(small):
    assert [r.meta["subject"] for r in small] == ["s1", "s2"]
    trials = [t for r in small for t in r.trials]
    assert len(trials) == 2 * 2 * 3 * 3 * 4
    for field, values in (("action", ACTIONS), ("object", OBJECTS), ("pose", POSES)):
        counts = {v: sum(getattr(t, field) == v for t in trials) for v in values}
        assert len(set(counts.values())) == 1, counts
    for t in trials:
        assert t.n_frames == 95
        assert 0 < t.extra["onset"] < t.n_frames


@pytest.mark.slow
def test_full_protocol_is_900_trials():
    recs = simulate_protocol(seed=0)
    assert len(recs) == 5 and sum(len(r.trials) for r in recs) == 900


def _by_action(recs, action):
    for rec in recs:
        for tr in rec.trials:
            if tr.action == action:
                f, _ = rec.trial_frames(tr)
                yield f.astype(np.float64), tr.extra["onset"]


def test_push_moves_load_from_distal_to_proximal(small):
    moved = []
    for f, onset in _by_action(small, "push"):
        before_d, after_d = f[:onset, DISTAL].sum(1).mean(), f[-10:, DISTAL].sum(1).mean()
        before_p, after_p = f[:onset, PROXIMAL].sum(1).mean(), f[-10:, PROXIMAL].sum(1).mean()
        moved.append(after_d < 0.5 * before_d and after_p > before_p + 100)
    assert np.mean(moved) > 0.8


def test_bump_is_transient(small):
    ok = []
    for f, onset in _by_action(small, "bump"):
        total = f[:, DISTAL].sum(1)
        base, peak, end = total[:onset].mean(), total[onset:onset + 8].max(), total[-15:].mean()
        ok.append(peak > 1.2 * base and abs(end - base) < 0.25 * base)
    assert np.mean(ok) > 0.8


def test_pull_moves_contact_toward_fingertip(small):
    rows = np.repeat(np.arange(13), 6)  # distal pads: row 0 is the tip
    moved = []
    for f, onset in _by_action(small, "pull"):
        pads = f[:, DISTAL].reshape(len(f), 3, 78)

        def centroid(frames):
            s = frames.sum(axis=(0, 1))
            return (s * rows).sum() / max(s.sum(), 1)

        late = pads[onset + 5:]
        gone = late.sum() < 0.2 * pads[:onset].sum() * len(late) / max(onset, 1)
        moved.append(gone or centroid(late) < centroid(pads[:onset]) - 0.5)
    assert np.mean(moved) > 0.8


def test_hold_changes_slowly(small):
    """A grip is smooth: its largest one-frame change of total load is far below a bump's."""
    def jump(action):
        return np.median([np.abs(np.diff(f[onset:, DISTAL].sum(1))).max() / max(f[:onset, DISTAL].sum(1).mean(), 1)
                          for f, onset in _by_action(small, action)])
    assert jump("hold") < 0.5 * jump("bump")


def test_session_places_events_at_script_times():
    script = demo_script(n_events=6, seed=2)
    assert sorted(e.action for e in script) == sorted(["pull", "push", "hold", "bump", "pull", "push"])
    rec = simulate_session(script, seed=2)
    assert len(rec.trials) == 6 and rec.meta["synthetic"]
    for ev, tr in zip(script, rec.trials, strict=True):
        assert tr.action == ev.action and tr.first <= tr.extra["onset"] <= tr.last
        assert abs(rec.timestamps[tr.extra["onset"]] - ev.time) < 0.05
    # idle between events: the hand is open, nothing touches
    gaps = [rec.frames[a.last + 1:b.first] for a, b in zip(rec.trials, rec.trials[1:], strict=False)]
    assert all(not g.any() for g in gaps if len(g))
    assert not rec.frames[: rec.trials[0].first].any()


def test_session_is_deterministic():
    script = [ScriptedEvent(3.0, "bump", "s2", "ball", "up"), ScriptedEvent(7.0, "pull", "s1", "plank", "down")]
    a, b = simulate_session(script, seed=4), simulate_session(script, seed=4)
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.timestamps, b.timestamps)


@pytest.mark.parametrize("bad, message", [
    ([ScriptedEvent(3.0, "kick", "s1", "ball", "up")], "unknown action 'kick'"),
    ([ScriptedEvent(3.0, "pull", "s1", "cube", "up")], "unknown object 'cube'"),
    ([ScriptedEvent(3.0, "pull", "s1", "ball", "up"), ScriptedEvent(4.0, "push", "s1", "ball", "up")], "closer"),
])
def test_session_rejects_bad_scripts(bad, message):
    with pytest.raises(ValueError, match=message):
        simulate_session(bad)


def test_cli_writes_protocol_and_session(tmp_path, capsys):
    import argparse

    from firmware_io.commands import simulate_cli
    from runtime import cli

    parser = argparse.ArgumentParser()
    simulate_cli.add_arguments(parser)
    assert simulate_cli.main(parser.parse_args(["--out", str(tmp_path), "--subjects", "1", "--runs", "1"])) == 0
    assert (tmp_path / "subject_s1.hrec").exists()
    assert "36 trials" in capsys.readouterr().out
    assert simulate_cli.main(parser.parse_args(["--out", str(tmp_path), "--session", "4", "--seed", "1"])) == 0
    assert (tmp_path / "session_seed1.hrec").exists() and (tmp_path / "session_seed1.json").exists()
    with pytest.raises(SystemExit) as stop:  # a count of 0 is refused as it is read, before any work
        cli.main(["simulate", "--out", str(tmp_path / "f" / "x"), "--runs", "0"])
    assert stop.value.code == 2 and not (tmp_path / "f").exists()
    assert capsys.readouterr().err.startswith("handover simulate: argument --runs: must be at least 1, got 0")
