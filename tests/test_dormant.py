"""Dormant class and continuous mode: idle streams, the 5-class data set and model, replay
through the daemon's hot path, the stream metrics, and ``./dev bench dormant``. Synthetic data."""

from __future__ import annotations

import argparse
import math

import numpy as np
import pytest

from firmware_io.layout import SensorLayout
from firmware_io.recordings.recording import Recording
from firmware_io.sim import ScriptedEvent, simulate_protocol
from firmware_io.sim import constants as K
from firmware_io.sim.idle import SOURCES, hold_motion, min_jerk, plan_hold, simulate_idle, simulate_mixed
from trainer import dormant
from trainer import streams_eval as se

LAYOUT = SensorLayout.sdh2()
DISTAL = LAYOUT.columns("distal")


@pytest.fixture(scope="module")
def idle() -> Recording:
    return simulate_idle(90.0, seed=4)


@pytest.fixture(scope="module")
def protocol() -> list[Recording]:
    return simulate_protocol(seed=2, n_subjects=2, runs=1)


@pytest.fixture(scope="module")
def dds(protocol, idle) -> dormant.DormantDataset:
    return dormant.build_dormant_dataset(protocol, [idle], T=15, pads="distal", seed=0, per_source=30)


@pytest.fixture(scope="module")
def models(tmp_path_factory, protocol, dds):
    """A tiny 5-class and a tiny 4-class model, exported and loaded by the runtime's loader."""
    from runtime.model import load_model
    from trainer.classifier import BowSVC
    from trainer.dataset import build_dataset

    out = tmp_path_factory.mktemp("dormant-models")
    common = {"pads": dds.pads, "pad_sizes": dds.pad_sizes, "fullscale": 4095.0, "fraction": 0.15,
              "sample_rate_hz": 1 / K.FRAME_PERIOD_S}
    five = BowSVC(C=10.0, gamma=10.0, random_state=0).fit(dds.X, dds.y)
    p5 = dormant.export(five, out / "five.onnx", dormant_class=dormant.DORMANT, **common,
                        training={"data_fingerprint": dds.fingerprint, "n_trials": 72})
    ds = build_dataset(protocol, T=15, pads="distal")
    four = BowSVC(C=10.0, gamma=10.0, random_state=0).fit(ds.X, ds.y)
    p4 = dormant.export(four, out / "four.onnx", dormant_class=None, **common,
                        training={"data_fingerprint": ds.fingerprint, "n_trials": ds.n_trials})
    return {"five": load_model(p5), "four": load_model(p4)}


# -- idle streams ----------------------------------------------------------------------------------
def test_idle_stream_is_deterministic_and_parts_differ():
    a = simulate_idle(30.0, seed=9)
    b = simulate_idle(30.0, seed=9)
    c = simulate_idle(30.0, seed=9, part=1)
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.timestamps, b.timestamps)
    assert a.meta["source_codes"] == b.meta["source_codes"]
    assert a.frames.shape != c.frames.shape or not np.array_equal(a.frames, c.frames)


def test_idle_stream_format_and_sources(idle):
    assert idle.meta["synthetic"] is True
    assert idle.n_frames * K.FRAME_PERIOD_S >= 90.0
    assert idle.trials == []
    code = np.asarray(idle.meta["source_codes"])
    assert code.shape == (idle.n_frames,)
    assert set(np.unique(code)) <= set(range(len(SOURCES)))
    assert idle.frames.max() <= 4095 and not idle.frames[:, ~LAYOUT.static_mask()].any()
    open_ = code == SOURCES.index("open")
    quiet = code == SOURCES.index("quiet")
    assert open_.any() and quiet.any()
    assert not idle.frames[open_].any(), "an open hand reads exactly 0"
    assert (idle.frames[quiet][:, DISTAL].max(axis=1) > 0).all(), "a held object presses the distal pads"
    assert not idle.frames[:, LAYOUT.columns("proximal")].any(), "nobody pushes the object into the palm"


def test_min_jerk_move_starts_and_ends_at_rest():
    tau = np.linspace(-0.2, 1.2, 1401)
    pos, acc = min_jerk(tau)
    assert pos[0] == 0 and pos[-1] == 1 and np.all(np.diff(pos) >= 0)
    assert math.isclose(acc.max(), 1.0, rel_tol=1e-3) and math.isclose(acc.min(), -1.0, rel_tol=1e-3)
    assert abs(np.trapezoid(acc, tau)) < 1e-3, "the hand is at rest again after a move"


def test_regrasp_dips_the_force_and_arm_moves_shift_load():
    rng = np.random.default_rng(0)
    plan = None
    for _ in range(50):  # a hold with both a regrasp and an arm move
        plan = plan_hold(rng, 90.0, obj="plank", pose="up")
        if plan.regrasps and plan.moves:
            break
    assert plan is not None and plan.regrasps and plan.moves
    t = (np.arange(plan.n_frames * K.SCANS_PER_FRAME) + 0.5) * K.FRAME_PERIOD_S / K.SCANS_PER_FRAME
    m, gain = hold_motion(plan, t, np.random.default_rng(1))
    r = plan.regrasps[0]
    before = m.nd[:, np.searchsorted(t, r.start_s - 0.05)].sum()
    bottom = m.nd[:, np.searchsorted(t, r.start_s + r.dip_s)].sum()
    assert bottom < 0.8 * before
    assert gain[np.searchsorted(t, r.start_s + r.dip_s + 0.01)] < gain[np.searchsorted(t, r.start_s - 0.01)], \
        "creep starts over after a regrasp"
    mv = plan.moves[0]
    during = (t > mv.start_s) & (t < mv.start_s + mv.duration_s)
    still = (t > plan.close_s + 0.5) & (t < mv.start_s)
    if still.sum() > 10:
        assert np.ptp(m.nd[:, during], axis=1).max() > np.ptp(m.nd[:, still], axis=1).max()


def test_mixed_stream_fills_gaps_with_idle_holds():
    events = [ScriptedEvent(3.0, "pull", "s1", "ball", "down"), ScriptedEvent(18.0, "bump", "s2", "plank", "up")]
    rec = simulate_mixed(events, seed=5)
    code = np.asarray(rec.meta["source_codes"])
    assert len(rec.trials) == 2
    for tr in rec.trials:
        assert (code[tr.first:tr.last + 1] == -1).all()
        assert tr.first <= tr.extra["onset"] <= tr.last
    gap = slice(rec.trials[0].last + 1, rec.trials[1].first)
    assert (code[gap] == SOURCES.index("quiet")).any(), "the gap between the events holds an untouched object"


# -- the 5-class data set and model -------------------------------------------------------------------
def test_action_window_positions():
    starts = dormant.action_starts(onset=30, n_frames=95, T=15)
    assert starts.min() == 30 - 15 + dormant.ACTION_VIEW_MIN and starts.max() == 30 + dormant.ACTION_LATE_MAX
    assert len(dormant.action_starts(onset=90, n_frames=95, T=15)) == 0


def test_ramp_windows_follow_the_hold_grip_after_the_onset_windows(monkeypatch):
    monkeypatch.setattr(dormant, "RAMP_WINDOWS", {"hold": (3, 12)})
    rng = np.random.default_rng(0)
    starts = dormant.ramp_starts("hold", onset=30, n_frames=95, T=15, rng=rng)
    assert len(starts) == len(set(starts)) == 3
    assert all(30 + dormant.ACTION_LATE_MAX < s <= 30 + 12 for s in starts), "after the onset windows, within the ramp"
    assert dormant.ramp_starts("pull", onset=30, n_frames=95, T=15, rng=rng) == []
    assert dormant.ramp_starts("hold", onset=30, n_frames=30 + 5 + 15, T=15, rng=rng) == [35], "cut by the trial's end"
    assert dormant.ramp_starts("hold", onset=90, n_frames=95, T=15, rng=rng) == []


def test_dormant_dataset(dds, protocol):
    assert dds.X.shape[1:] == (len(DISTAL), 15) and dds.X.dtype == np.float32
    assert set(dds.y) == {"pull", "push", "hold", "bump", "dormant"}
    s = dds.summary()
    assert s["per_origin"]["pre_onset"] > 0 and s["per_origin"]["idle:quiet"] == 30
    assert all(dds.y[dds.origin != "action"] == "dormant")
    n_hold, extra = s["per_class"]["hold"], dormant.RAMP_WINDOWS["hold"][0]
    assert n_hold == s["per_class"]["pull"] * (dormant.WINDOWS_PER_TRIAL + extra) // dormant.WINDOWS_PER_TRIAL, \
        "every hold trial adds its ramp windows"
    idle_groups = set(dds.groups[np.char.startswith(dds.origin, "idle")].tolist())
    assert idle_groups <= {f"idle{i}" for i in range(dormant.IDLE_FOLDS)} and len(idle_groups) > 1
    # a pre-onset window is the grasp alone: it matches frames that end before the onset
    tr = next(t for t in protocol[0].trials if t.extra["onset"] >= 16)
    frames = protocol[0].frames[tr.first:tr.last + 1, DISTAL]
    o = tr.extra["onset"]
    assert any(np.array_equal(x, frames[o - 16:o - 1].T) for x in dds.X[dds.origin == "pre_onset"])


def test_windows_are_attributed_to_the_rarest_transition_in_view():
    names = list(SOURCES)
    q, g, r, o = (names.index(n) for n in ("quiet", "grasp", "release", "open"))
    code = np.array([o] * 5 + [g] * 3 + [q] * 20 + [r] * 2 + [o] * 20)
    view = dormant.in_view(code, names, T=5)
    assert view[:4] == [None] * 4
    assert view[5] == "grasp" and view[11] == "grasp" and view[12] == "quiet", "grasp in view until it leaves"
    assert view[28] == "release" and view[33] == "release" and view[34] == "open"


def test_session_windows_show_the_hand_closing_and_opening():
    from firmware_io.sim import simulate_session

    events = [ScriptedEvent(3.0, "pull", "s1", "ball", "down"), ScriptedEvent(8.0, "hold", "s2", "plank", "up")]
    rec = simulate_session(events, seed=3)
    X, origin, groups = dormant.session_windows([rec], DISTAL, 15, np.random.default_rng(0), per_kind=1000)
    origin = np.asarray(origin)
    assert {"session:place", "session:take_away"} <= set(origin.tolist()) and set(groups) <= {"s1", "s2"}
    for x, o in zip(X, origin, strict=True):
        level = x.max(axis=0)  # per frame of the window
        if o == "session:place":  # the object is held at the window's end (the grasp built up before)
            assert level[-1] > 0
        else:  # the hand opens: the pressure falls within the window (or the object was already gone)
            assert level[0] >= level[-1]
    assert (origin == "session:take_away").sum() == 2 * (10 + 14 - dormant.TRANSITION_VISIBLE), \
        "every window from 3 frames into each 0.3 s opening until it has left the window"


def test_five_class_model_loads_with_its_dormant_class(models):
    five, four = models["five"], models["four"]
    assert five.meta.dormant_class == "dormant" and five.meta.n_classes == 5
    assert four.meta.dormant_class is None and four.meta.n_classes == 4
    labels, scores = five.run(np.zeros((2, 15, len(DISTAL)), np.float32))
    assert scores.shape == (2, 5)
    assert five.meta.classes[int(labels[0])] == "dormant", "an open hand (all zeros) is dormant"


# -- replay through the daemon ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def short_mixed() -> Recording:
    rec = simulate_mixed([ScriptedEvent(3.0, "pull", "s1", "ball", "down"),
                          ScriptedEvent(9.0, "hold", "s2", "cylinder", "horizontal")], seed=6)
    return Recording(rec.layout, rec.frames[:400], rec.timestamps[:400], [], {})


def test_continuous_replay_with_the_plain_rule_reports_exactly_the_changes(models, short_mixed):
    five = models["five"]
    plain = {"confirm_frames": 1, "min_margin": 0.0, "rearm_frames": 0}
    decisions = se.replay(short_mixed, five, "continuous", rule=plain)
    x = short_mixed.frames[:, DISTAL].astype(np.float32)
    windows = np.lib.stride_tricks.sliding_window_view(x, 15, axis=0).transpose(0, 2, 1)
    labels, _ = five.run(windows)
    names = [five.meta.classes[int(k)] for k in labels]
    expected, previous = [], None
    for i, name in enumerate(names):
        if name != "dormant" and name != previous:
            expected.append((i + 14, name))
        previous = name
    assert [(d.frame, d.cls) for d in decisions] == expected
    assert all(d.latency_us > 0 for d in decisions)


@pytest.mark.parametrize("rule", [
    {"confirm_frames": 3, "min_margin": 0.0, "rearm_frames": 6},
    {"confirm_frames": 2, "min_margin": 0.5, "rearm_frames": 0},
    {},  # the config defaults
])
def test_continuous_replay_matches_the_offline_rule(models, short_mixed, rule):
    five = models["five"]
    labels, scores = se.frame_decisions(short_mixed, five, batch=97)  # batches need not divide the stream
    assert labels.shape == (short_mixed.n_frames - 14,) and scores.shape == (len(labels), 5)
    offline = se.apply_rule(labels, scores, five.meta, rule)
    online = se.replay(short_mixed, five, "continuous", rule=rule)
    assert [(d.frame, d.cls) for d in online] == [(d.frame, d.cls) for d in offline]


def test_daemon_serve_refuses_a_model_that_does_not_fit(models):
    from runtime.config import config_from_dict
    from runtime.daemon import Daemon

    cfg = config_from_dict({"scene": {"pads": "distal", "mode": "continuous"}, "sinks": {"stdout": False}})
    with pytest.raises(ValueError, match="dormant class"):
        Daemon(cfg).serve(models["four"], LAYOUT)
    daemon = Daemon(cfg)
    daemon.serve(models["five"], LAYOUT)
    assert daemon.detector.rule.continuous is not None and daemon.detector.rule.continuous.confirm_frames == cfg.continuous.confirm_frames


def test_threshold_replay_fires_once_per_crossing(models):
    four = models["four"]
    frames = np.zeros((200, LAYOUT.n_taxels), np.uint16)
    frames[50:80, DISTAL[:10]] = 700  # above 15 % of 4095 = 614
    frames[120:125, DISTAL[:10]] = 700
    rec = Recording(LAYOUT, frames, np.arange(200) * K.FRAME_PERIOD_S, [], {})
    frames_of = [d.frame for d in se.replay(rec, four, "threshold")]
    assert frames_of == [50 + 14, 120 + 14]
    assert se.replay(rec, four, "baseline")[0].frame == 64
    with pytest.raises(ValueError, match="dormant"):
        se.replay(rec, four, "continuous")


# -- metrics on a hand-made case -------------------------------------------------------------------
def test_score_hand_made_case():
    period = 0.03
    truths = [se.Truth(100, 150, "pull"), se.Truth(300, 350, "bump"), se.Truth(600, 650, "hold")]
    decisions = [se.Decision(105, "pull"), se.Decision(110, "hold"), se.Decision(200, "bump"),
                 se.Decision(299, "hold"), se.Decision(900, "push"), se.Decision(96, "pull")]
    sources = np.full(1000, "quiet", dtype=object)
    sources[900] = "arm_move"
    r = se.score(sorted(decisions, key=lambda d: d.frame), truths, 1000, period, sources)
    # frame 96 is before 100 - 2: a false event; 105 detects the pull; 110 duplicates it;
    # 200 false; 299 (within 2 frames early) detects the bump with the wrong class; the hold is missed
    assert (r["detected"], r["missed"], r["wrong_class"], r["correct"], r["duplicates"]) == (2, 1, 1, 1, 1)
    assert r["false_events"] == 3
    owned = 3 * 53
    assert math.isclose(r["idle_hours"], (1000 - owned) * period / 3600)
    assert math.isclose(r["false_per_hour"], 3 / r["idle_hours"])
    assert r["false_by_source"] == {"arm_move": 1, "quiet": 2}
    assert math.isclose(r["delay_s"]["min"], -period) and math.isclose(r["delay_s"]["max"], 5 * period)
    assert r["per_action"]["hold"] == {"n": 1, "detected": 0, "correct": 0}
    merged = se.merge_idle([r, r])
    assert merged["false_events"] == 6 and math.isclose(merged["false_per_hour"], r["false_per_hour"])


def test_score_without_events_counts_every_decision_false():
    r = se.score([se.Decision(10, "bump")], [], 3600, 1.0)
    assert r["false_events"] == 1 and math.isclose(r["false_per_hour"], 1.0) and r["recall"] is None


# -- CLI -------------------------------------------------------------------------------------------------
def _args(*argv: str) -> argparse.Namespace:
    from benchmarks import dormant_cli

    parser = argparse.ArgumentParser()
    dormant_cli.add_arguments(parser)
    return parser.parse_args(list(argv))


@pytest.mark.parametrize(("argv", "message"), [
    (["--eval-seed", "0"], "--eval-seed must differ"),
    (["--pads", "nonsense"], "--pads"),
    (["--W", "20"], "T >= W + 1"),
    (["--events", "0"], "must be positive"),
])
def test_cli_refuses_bad_options_in_one_line(argv, message, capsys, tmp_path):
    from benchmarks.__main__ import main as bench

    assert bench(["dormant", "--out", str(tmp_path), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("./dev bench dormant: ") and message in err and "\n" not in err


@pytest.mark.slow
def test_cli_quick_run_writes_results(tmp_path, capsys):
    import json

    from benchmarks import dormant_cli

    code = dormant_cli.main(_args("--quick", "--json", "--quiet", "--out", str(tmp_path), "--idle-hours", "0.05",
                                  "--events", "6", "--train-idle-min", "2"))
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["synthetic"] is True and set(summary["modes"]) == set(dormant_cli.ORDER)  # the onset modes are `bench streams`' (results/streams.md)
    for name in ("dormant.json", "dormant.md", "dormant_timeline.png", "dormant_tradeoff.png", "dormant_sources.png", "dormant_rules.png",
                 "dormant-model/dormant.onnx", "dormant-model/paper.onnx"):
        assert (tmp_path / name).is_file(), name
    full = json.loads((tmp_path / "dormant.json").read_text())
    assert set(full["loso"]["recall"]) == {"pull", "push", "hold", "bump", "dormant"}
    assert set(full["rule"]["chosen"]) == {"confirm_frames", "min_margin", "rearm_frames"}
    assert full["offline_rule_matches_daemon"] is True
    text = (tmp_path / "dormant.md").read_text()
    assert "synthetic" in text and "./dev bench dormant" in text


def test_the_dormant_windows_training_cuts_are_the_windows_the_daemon_serves(tmp_path):
    """``trigger_windows`` (the idle's dormant cases) and the daemon's Detector on the same idle stream, with a
    model that dates its windows back: the same windows, frame for frame, and some of them dated back."""
    import time

    from firmware_io.client import Frame
    from runtime.config import config_from_dict
    from runtime.detector import Detector
    from runtime.model import load_model
    from runtime.trigger_settings import resolve_trigger
    from tests.tiny_models import tiny_model_bytes, write_model

    rec = simulate_idle(180.0, seed=3, part=0)
    model = load_model(write_model(tmp_path, "m.onnx", tiny_model_bytes(trigger={"kind": "onset", "back_frames": 3})))
    pads = list(model.meta.pads)
    det = Detector.from_config(config_from_dict({"scene": {"pads": ",".join(map(str, pads)), "mode": "trigger"}}))
    det.swap(model, rec.layout)
    stamps = np.rint(rec.timestamps * 1000).astype(np.int64)
    served, backs = [], []
    for i in range(rec.n_frames):
        if (d := det.feed(Frame(i, int(stamps[i]), time.perf_counter(), rec.frames[i]))) is not None:
            served.append(d.first)
            backs.append(det.trigger.back)
    lay = rec.layout
    cols = lay.columns(pads)
    cut, _, _ = dormant.trigger_windows([rec], cols, model.meta.T, resolve_trigger(None, model.meta.trigger),
                                        lay.pad_sizes(pads), lay.fullscale, lay.pad_fingers(pads))
    assert len(cut) == len(served) > 0 and any(backs), backs
    for first, window in zip(served, cut, strict=True):
        assert np.array_equal(rec.frames[first:first + model.meta.T][:, cols].T.astype(np.float32), window)
