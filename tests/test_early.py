"""Early decisions: the metadata and rule (runtime.early), their fitting (trainer.early), the heads in
the one graph and the loader's checks, and the daemon reporting before the full window."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from runtime.decision import margin_of as margin
from runtime.early import NEVER, EarlyRule, EarlySpec, EarlySpecError

SPEC = {"points": [4, 8], "calibration": [[2.0, 0.0], [2.0, 1.0]], "threshold": 0.8, "agree": False}


def test_spec_round_trips_and_refuses_nonsense():
    spec = EarlySpec.from_meta(SPEC, T=15)
    assert EarlySpec.from_meta(spec.to_meta(), T=15) == spec
    for bad, word in [({**SPEC, "points": [8, 4]}, "ascend"), ({**SPEC, "points": [4, 15]}, "T-1"),
                      ({**SPEC, "calibration": [[1.0, 0.0]]}, "one [a, b] pair"),
                      ({**SPEC, "threshold": 2.0}, "probability"), ({**SPEC, "agree": "yes"}, "true or false"),
                      ([4, 8], "object")]:
        with pytest.raises(EarlySpecError, match=word.replace("[", r"\[").replace("]", r"\]")):
            EarlySpec.from_meta(bad, T=15)


def test_rule_reports_on_confidence_agreement_and_allowed_classes():
    spec = EarlySpec.from_meta(SPEC, T=15)
    sure, unsure = np.array([3.2, 0.1, 1.0]), np.array([1.1, 0.9, 1.0])
    assert margin(sure, 0) == pytest.approx(2.2) and margin(unsure, 0) == pytest.approx(0.1)
    names = ("a", "b", "c")
    rule = EarlyRule(spec, names)
    assert rule.index_of(4) == 0 and rule.index_of(8) == 1 and rule.index_of(5) == -1
    assert rule.report_now(0, 0, sure, -1)  # sigmoid(4.4) > 0.8
    assert not rule.report_now(0, 0, unsure, -1)  # sigmoid(0.2) < 0.8
    assert not EarlyRule(spec, names, frozenset({"b"})).report_now(0, 0, sure, -1)  # the scene keeps a to T
    trained = EarlySpec(spec.points, spec.calibration, spec.threshold, False, ("b", "c"))
    assert not EarlyRule(trained, names).report_now(0, 0, sure, -1)  # training kept a to T
    agree = EarlyRule(EarlySpec(spec.points, spec.calibration, spec.threshold, True), names)
    assert not agree.report_now(0, 0, sure, -1) and agree.report_now(1, 0, sure, 0)
    assert not agree.report_now(1, 0, sure, 2)
    never = EarlyRule(EarlySpec(spec.points, spec.calibration, NEVER, False), names)
    assert not never.report_now(0, 0, np.array([1e6, 0.0, 0.0]), -1)


def test_platt_and_rule_choice_on_made_up_answers():
    from trainer.early import cascade, choose_rule, confidences, platt

    a, b = platt(np.array([0.1, 2.0, 3.0]), np.array([True, True, True]))  # never wrong: still finite, cautious
    assert np.isfinite([a, b]).all() and 1 / (1 + np.exp(-(a * 3.0 + b))) < 1.0
    rng = np.random.default_rng(0)
    n = 400
    truth = rng.integers(0, 3, n)
    m4 = rng.uniform(0, 2, n)
    lab4 = np.where(m4 > 0.6, truth, (truth + 1) % 3)  # a head right exactly when its margin is large
    m8 = rng.uniform(0, 2, n)
    lab8 = np.where(m8 > 0.2, truth, (truth + 1) % 3)
    choice = choose_rule(np.stack([lab4, lab8]), np.stack([m4, m8]), truth.copy(), truth, (4, 8), 15)
    assert choice.full_accuracy == 1.0 and choice.accuracy >= 0.98
    assert choice.mean_frames < 15  # the margin tells right from wrong, so it reports early
    _, said = cascade(np.stack([lab4, lab8]), confidences(np.stack([m4, m8]), choice.spec.calibration),
                          truth, np.full(3, choice.spec.threshold), choice.spec.agree)
    assert np.mean(said == truth) == pytest.approx(choice.accuracy)
    useless = choose_rule(np.stack([(truth + 1) % 3] * 2), np.stack([m4, m8]), truth.copy(), truth, (4, 8), 15)
    assert useless.spec.threshold == NEVER and useless.mean_frames == 15  # wrong heads: always wait for T


@pytest.fixture(scope="module")
def early_model(tmp_path_factory):
    """A 4-class default model with early heads at 4 and 8 frames, on a small simulated protocol (synthetic)."""
    from firmware_io.sim import simulate_protocol
    from trainer import early
    from trainer.dataset import build_dataset
    from trainer.measure import export_metadata
    from trainer.onnx_export import export_onnx

    ds = build_dataset(simulate_protocol(seed=0, n_subjects=3, runs=1), T=15, pads="distal")
    make = early.head_factory(ds.pad_sizes)
    heads = early.fit_early(ds.X, ds.y, ds.groups, make, make, points=(4, 8))
    full = make(15).fit(ds.X, ds.y)
    path = export_onnx(full, tmp_path_factory.mktemp("early") / "early.onnx", export_metadata(ds, full, seed=0),
                       early=heads)
    return path, ds, heads, full


def test_heads_in_the_file_answer_like_the_fitted_heads(early_model):
    from runtime.model import load_model

    path, ds, heads, full = early_model
    model = load_model(path)
    assert model.early == heads.spec and model.early.points == (4, 8)
    frames = np.ascontiguousarray(ds.X[:20].transpose(0, 2, 1))
    for index, (head, p) in enumerate(zip(heads.models, model.early.points, strict=True)):
        want = head.predict(ds.X[:20, :, :p])
        newest = np.zeros_like(frames)  # at point p the ring's newest T frames end with the window's first p
        newest[:, -p:] = frames[:, :p]
        got = [model.meta.classes[int(model.run_head(index, newest[i:i + 1])[0][0])] for i in range(20)]
        assert got == list(want)
    labels, _ = model.run(frames)
    assert [model.meta.classes[i] for i in labels] == list(full.predict(ds.X[:20]))


def test_heads_that_disagree_with_the_metadata_are_refused_in_one_line(early_model, tmp_path):
    import onnx

    from runtime.model import METADATA_KEY, ModelContractError, load_model

    path, *_ = early_model
    proto = onnx.load(str(path))
    props = {p.key: p.value for p in proto.metadata_props}
    meta = json.loads(props[METADATA_KEY])
    for name, change in [("fewer", {**meta["early"], "points": [4], "calibration": meta["early"]["calibration"][:1]}),
                         ("none", None)]:
        changed = dict(meta)
        if change is None:
            changed.pop("early")
        else:
            changed["early"] = change
        onnx.helper.set_model_props(proto, {**props, METADATA_KEY: json.dumps(changed)})
        bad = tmp_path / f"{name}.onnx"
        bad.write_bytes(proto.SerializeToString())
        with pytest.raises(ModelContractError, match=r"early-head outputs .* disagree with the metadata") as info:
            load_model(bad)
        assert "\n" not in str(info.value)


def test_a_model_without_early_heads_serves_as_before(tmp_path):
    from runtime.model import load_model
    from tests.tiny_models import tiny_model_bytes

    path = tmp_path / "plain.onnx"
    path.write_bytes(tiny_model_bytes())
    model = load_model(path)
    assert model.early is None
    assert model.run(np.zeros((1, 15, 234), np.float32))[1].shape == (1, 4)


def test_the_daemon_reports_a_pull_before_the_full_window(early_model):
    """A simulated session through the daemon's hot path: events come from the early heads, one per event."""
    from firmware_io.sim import demo_script, simulate_session
    from runtime.model import load_model
    from trainer.streams_eval import replay, session_outcomes

    path, *_ = early_model
    model = load_model(path)
    session = simulate_session(demo_script(8, seed=5), seed=5)
    decisions = replay(session, model, "onset")
    outcome = session_outcomes(decisions, session.trials)
    assert len(decisions) == len(session.trials)  # one report per event, none outside
    delays = [d.frame - int(t.extra["onset"]) for d, t in zip(decisions, session.trials, strict=True)]
    assert np.median(delays) < 15  # without heads a report comes T frames after the window's start
    assert outcome["report_minus_onset_frames"]["median"] == pytest.approx(np.median(delays))


def test_scene_early_events_keeps_the_others_for_the_full_window(early_model):
    from firmware_io.sim import demo_script, simulate_session
    from runtime.config import ConfigError, config_from_dict
    from runtime.model import load_model
    from trainer.streams_eval import replay

    with pytest.raises(ConfigError, match=r"scene\.early_events: 'wave' not in scene\.events"):
        config_from_dict({"scene": {"early_events": ["wave"]}})
    said = config_from_dict({"scene": {"mode": "continuous", "early_events": ["pull"]}}).warnings
    assert [w for w in said if w.startswith("scene.early_events: has no effect in continuous mode")]
    assert not config_from_dict({"scene": {"early_events": ["pull"]}}).warnings, "trigger mode uses it"
    path, *_ = early_model
    model = load_model(path)
    session = simulate_session(demo_script(8, seed=5), seed=5)
    never = replay(session, model, "onset", scene={"early_events": []})
    early = replay(session, model, "onset")
    assert [d.cls for d in never] and all(
        d.frame - int(t.extra["onset"]) >= 13 for d, t in zip(never, session.trials, strict=True))
    assert sum(d.frame for d in early) < sum(d.frame for d in never)


def test_the_classes_training_allows_early_are_the_only_ones_the_daemon_reports_early(early_model, tmp_path):
    import dataclasses

    from firmware_io.sim import demo_script, simulate_session
    from runtime.model import load_model
    from trainer import early
    from trainer.measure import export_metadata
    from trainer.onnx_export import export_onnx
    from trainer.streams_eval import replay

    path, ds, heads, full = early_model
    session = simulate_session(demo_script(8, seed=5), seed=5)
    kept = early.EarlyHeads(heads.models, dataclasses.replace(heads.spec, classes=()))
    none_early = export_onnx(full, tmp_path / "none.onnx", export_metadata(ds, full, seed=0), early=kept)
    assert load_model(none_early).early.classes == ()
    never = replay(session, load_model(path), "onset", scene={"early_events": []})
    assert [(d.frame, d.cls) for d in replay(session, load_model(none_early), "onset")] == \
        [(d.frame, d.cls) for d in never]
    assert EarlySpec.from_meta({**SPEC, "classes": ["pull"]}, T=15).to_meta()["classes"] == ["pull"]
    with pytest.raises(EarlySpecError, match="classes must be a list"):
        EarlySpec.from_meta({**SPEC, "classes": "pull"}, T=15)


def test_the_rule_keeps_a_class_that_costs_false_events_for_the_full_window():
    from trainer.early import choose_rule

    truth = np.r_[np.zeros(100, int), np.ones(50, int), np.full(50, 2)]  # dormant 0, hold 1, pull 2
    lab = truth.copy()[None]
    lab[0, :10] = 1  # the head reads 10 dormant windows (arm moves) as holds, sure of it
    margins = np.full((1, len(truth)), 3.0)
    alone = choose_rule(lab, margins, truth.copy(), truth, (4,), 15, dormant=0)
    assert alone.mean_frames == 15 and alone.spec.classes is None, "one rule for all: nothing may come early"
    per = choose_rule(lab, margins, truth.copy(), truth, (4,), 15, dormant=0, classes=["dormant", "hold", "pull"])
    assert per.spec.classes == ("pull",) and per.accuracy == 1.0
    assert per.mean_frames == pytest.approx((150 * 15 + 50 * 4) / 200)


def test_nested_evaluation_fits_each_leave_groups_out_model_once(early_model):
    from trainer import early

    _, ds, _, _ = early_model
    made = []

    def make(p):
        made.append(p)
        return early.head_factory(ds.pad_sizes)(p)

    fits = early.Fits(ds.X, ds.y, ds.groups, (4, 8), make, make)
    ev = early.evaluate(fits)
    n_subjects = len(set(ds.groups.tolist()))
    pairs = n_subjects * (n_subjects - 1) // 2
    assert len(made) == 3 * (n_subjects + pairs)  # heads at 4, 8 and the full model, without one or two subjects
    heads = early.fit_early(ds.X, ds.y, ds.groups, make, make, (4, 8), fits=fits)
    assert len(made) == 3 * (n_subjects + pairs) + 2  # the final heads; the rule reuses the held-out models
    op = ev["operating_point"]
    assert ev["points"] == [4, 8, 15] and set(ev["curve_per_class"]) == set(ds.y.tolist())
    assert 4 <= op["mean_frames"] <= 15 and sum(op["reported_at"].values()) == len(ds.y)
    assert heads.spec.points == (4, 8)


def test_inspect_names_the_early_heads(early_model, capsys):
    from runtime.cli import main

    path, *_ = early_model
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "early heads: at 4, 8 frames" in out


def test_export_from_the_joblib_keeps_the_early_heads(early_model, tmp_path):
    import joblib

    from runtime.model import load_model
    from trainer.trained_file import export_trained

    path, _, heads, full = early_model
    import onnx

    from runtime.model import METADATA_KEY

    meta = json.loads({p.key: p.value for p in onnx.load(str(path)).metadata_props}[METADATA_KEY])
    saved = tmp_path / "model.joblib"
    joblib.dump({"model": full, "metadata": {k: meta[k] for k in ("pads", "pad_sizes", "trigger")}, "early": heads},
                saved)
    again = load_model(export_trained(saved, tmp_path / "again.onnx"))
    assert again.early == heads.spec


def test_onset_to_report_per_class():
    from trainer.streams_eval import per_class_delay

    per = per_class_delay([3, 5, 7, 16, 15], ["pull", "pull", "pull", "bump", "bump"])
    assert per["pull"]["median"] == 5 and per["bump"]["median"] == 15.5 and per["pull"]["p90"] == pytest.approx(6.6)


def _tiny_with_heads(T: int, points: list[int]) -> bytes:
    """A tiny model whose early heads answer like its full model (Identity outputs), one per point."""
    import onnx
    from onnx import TensorProto, helper

    from tests.tiny_models import tiny_model_bytes

    proto = onnx.load_from_string(tiny_model_bytes(T=T))
    for p in points:
        proto.graph.node.extend([helper.make_node("Identity", ["label"], [f"label_at_{p}"]),
                                 helper.make_node("Identity", ["scores"], [f"scores_at_{p}"])])
        proto.graph.output.extend([helper.make_tensor_value_info(f"label_at_{p}", TensorProto.INT64, ["N"]),
                                   helper.make_tensor_value_info(f"scores_at_{p}", TensorProto.FLOAT, ["N", 4])])
    meta = json.loads(proto.metadata_props[0].value)
    meta["early"] = {"points": points, "calibration": [[1.0, 0.0]] * len(points), "threshold": 0.9, "agree": False}
    del proto.metadata_props[:]
    helper.set_model_props(proto, {"handover": json.dumps(meta)})
    return proto.SerializeToString()


def test_a_file_claiming_hundreds_of_early_heads_is_refused_before_one_session_is_built(tmp_path, monkeypatch):
    """Each head is a session of its own: 998 heads held the watcher for 49 s and 270 MB before the
    warm-up bound refused it. The metadata is refused first, in one line."""
    import onnxruntime as ort

    from runtime.early import MAX_POINTS
    from runtime.model import ModelContractError, load_model

    many = tmp_path / "many.onnx"
    many.write_bytes(_tiny_with_heads(200, list(range(2, 200))))
    built = []
    real = ort.InferenceSession
    monkeypatch.setattr(ort, "InferenceSession", lambda *a, **k: built.append(1) or real(*a, **k))
    with pytest.raises(ModelContractError, match=f"198 heads, at most {MAX_POINTS}") as info:
        load_model(many)
    assert "\n" not in str(info.value) and len(built) <= 1  # the whole graph once, to read its metadata
    enough = tmp_path / "enough.onnx"
    enough.write_bytes(_tiny_with_heads(30, list(range(2, 2 + MAX_POINTS))))
    assert len(load_model(enough).early.points) == MAX_POINTS


def test_a_dormant_answer_is_never_reported_early_and_actions_keep_their_accuracy():
    from trainer.early import choose_rule

    truth = np.r_[np.zeros(300, int), np.ones(60, int)]  # many dormant (0) windows, few actions (1)
    lab = np.zeros((1, len(truth)), int)  # the early head says dormant, sure of it, for every window
    margins = np.full((1, len(truth)), 3.0)
    choice = choose_rule(lab, margins, truth.copy(), truth, (4,), 15, dormant=0)
    assert choice.mean_frames == 15  # nothing may be reported early: dormant waits for T
    assert choice.accuracy == 1.0


def test_the_rule_keeps_the_dormant_cases_accuracy_within_the_target_loss():
    from trainer.early import TARGET_LOSS, choose_rule

    truth = np.r_[np.ones(300, int), np.zeros(40, int)]  # many actions (1), few dormant (0) windows
    lab = np.ones((1, len(truth)), int)  # the early head says the action for every window
    margins = np.r_[np.full(300, 3.0), np.full(34, 0.0), np.full(6, 3.0)][None]  # 6 dormant windows look sure
    choice = choose_rule(lab, margins, truth.copy(), truth, (4,), 15, dormant=0)
    assert choice.mean_frames == 15 and choice.accuracy == 1.0
    # reporting early would lose 6/340 overall (within the loss) but 6/40 of the dormant cases: false events
    assert any(r["accuracy"] >= 1.0 - TARGET_LOSS and r["actions_accuracy"] == 1.0 and r["mean_frames"] < 15
               for r in choice.grid)
    chosen = next(r for r in choice.grid if r["threshold"] == choice.spec.threshold and r["agree"] == choice.spec.agree)
    assert chosen["dormant_accuracy"] >= 1.0 - TARGET_LOSS


def test_every_frame_that_runs_a_head_or_the_window_is_rehearsed_and_no_decision_changes(early_model):
    """On a simulated session with early heads: the detector asks for a rehearsal before exactly the
    frames at which it runs a head or the full window, and rehearsing there changes no report."""
    from firmware_io.client import Frame
    from firmware_io.sim import demo_script, simulate_session
    from runtime.config import config_from_dict
    from runtime.detector import Detector
    from runtime.model import load_model
    from trainer.streams_eval import TRIGGER_TABLE

    path, *_ = early_model
    session = simulate_session(demo_script(8, seed=5), seed=5)

    def serve(rehearse: bool) -> tuple[list[int], list[int], list[tuple]]:
        model = load_model(path)
        cfg = config_from_dict({"scene": {"pads": ",".join(map(str, model.meta.pads)),
                                          "events": list(model.meta.classes), "early_events": ["pull"]},  # the others run every head
                                "trigger": dict(TRIGGER_TABLE["onset"])})
        detector = Detector.from_config(cfg)
        detector.swap(model, session.layout)
        ran, asked, reports = [], [], []
        def counted(run):
            def call(*args):
                ran.append(detector.latest_frame.number)
                return run(*args)
            return call

        model.run_trusted, model.run_head = counted(model.run_trusted), counted(model.run_head)
        for i in range(session.n_frames):
            decision = detector.feed(Frame(i, round(i * 31.25), time.perf_counter(), session.frames[i]))
            if decision is not None:
                reports.append((decision.cls, decision.frame.number, decision.scores.tobytes()))
            if rehearse and detector.rehearsal_at() is not None:
                asked.append(i + 1)
                detector.rehearse()
        return ran, asked, reports

    ran, _, plain = serve(False)
    _, asked, rehearsed = serve(True)
    assert len(ran) > len(plain) > 0  # heads ran that did not report yet
    assert asked == ran and rehearsed == plain



def test_what_the_rehearsal_expects_at_each_frame_is_what_feed_then_runs(early_model):
    """``Detector._next_run`` (what the rehearsal warms) against what ``feed`` runs at the next frame, frame
    by frame, on a simulated session with early heads: the robot's arm moving between a window's heads,
    its settle time reaching into the first frame of another, a move across a whole window; and in
    continuous mode. They may differ only where the next frame brings news the expectation cannot have:
    the robot's 'arm moving' heard at that frame, and the ring's first full window (the rehearsal runs
    on the window the ring holds)."""
    from firmware_io.client import Frame
    from firmware_io.sim import demo_script, simulate_session
    from runtime.config import config_from_dict
    from runtime.detector import Detector
    from runtime.model import load_model
    from trainer.streams_eval import TRIGGER_TABLE

    path, *_ = early_model
    session = simulate_session(demo_script(8, seed=5), seed=5)
    settle = 16  # [control] arm_settle_s, 0.5 s at 32 Hz

    def serve(mode: str, arm: dict[int, bool]) -> tuple[list[tuple[int, int | None, int | None]], Detector]:
        model = load_model(path)
        cfg = config_from_dict({"scene": {"pads": ",".join(map(str, model.meta.pads)), "mode": mode,
                                          "events": list(model.meta.classes),
                                          **({"early_events": ["pull"]} if mode == "trigger" else {})},
                                "trigger": dict(TRIGGER_TABLE["onset"])})
        detector = Detector.from_config(cfg)
        detector.swap(model, session.layout)
        ran: list[int] = []
        trusted, head = model.run_trusted, model.run_head
        model.run_trusted = lambda window: ran.append(-1) or trusted(window)
        model.run_head = lambda index, window: ran.append(index) or head(index, window)
        frames = []  # (frame, what the detector expected it to run, what it ran)
        for i in range(session.n_frames):
            expected = detector._next_run()
            if i in arm:
                detector.set_arm_moving(arm[i], "test")
            ran.clear()
            detector.feed(Frame(i, round(i * 31.25), time.perf_counter(), session.frames[i]))
            assert len(ran) <= 1
            frames.append((i, expected, ran[0] if ran else None))
        return frames, detector

    def runs(frames) -> list[tuple[int, int]]:
        return [(i, run) for i, _, run in frames if run is not None]

    plain, _ = serve("trigger", {})
    assert [f for f in plain if f[1] != f[2]] == []
    ran = set(runs(plain))
    # each window's first frame, of the windows whose head at 4 frames did not report (their head at 8 ran)
    firsts = [i - 3 for i, run in ran if run == 0 and (i + 4, 1) in ran]
    assert any(run == -1 for _, run in ran) and len(firsts) > 5
    a, b, c = sorted(firsts)[0:5:2]
    # a: moving between its heads (at frames a+3 and a+7); b: the settle time ends at b's first frame; c: inside a move
    arm = {a + 5: True, a + 6: False, b - settle - 1: True, b - settle + 1: False, c - 8: True, c + 20: False}
    moved, detector = serve("trigger", arm)
    assert [f for f in moved if f[1] != f[2]] == []  # no word here falls on a frame that would run
    # what ran in the windows the arm touched after it moved: heads void, their ends judged dormant
    voided = {*range(a + 4, a + 15), *range(b, b + 15), *range(c, c + 15)}
    assert runs(moved) == [r for r in runs(plain) if r[0] not in voided] and detector.arm.dropped == 3
    continuous, detector = serve("continuous", {100: True, 101: False})
    assert [f for f in continuous if f[1] != f[2] and f[0] not in (14, 100)] == []
    assert runs(continuous) == [(i, -1) for i in range(14, session.n_frames) if not 100 <= i <= 101 + settle + 13]


def _tiny_with_lying_heads(points: list[int]) -> bytes:
    """A tiny model whose full answer is pull and whose early heads say bump with certainty, always."""
    import onnx
    from onnx import TensorProto, helper

    proto = onnx.load_from_string(_tiny_with_heads(15, points))
    keep = [n for n in proto.graph.node if not n.output[0].startswith(("label_at_", "scores_at_"))]
    del proto.graph.node[:]
    proto.graph.node.extend(keep)
    proto.graph.initializer.append(helper.make_tensor("certain_bump", TensorProto.FLOAT, [4], [0, 0, 0, 100.0]))
    for p in points:
        proto.graph.node.extend([helper.make_node("Add", ["scores", "certain_bump"], [f"scores_at_{p}"]),
                                 helper.make_node("ArgMax", [f"scores_at_{p}"], [f"label_at_{p}"], axis=1, keepdims=0)])
    return proto.SerializeToString()


def test_early_heads_that_contradict_the_full_model_are_disabled_with_one_note(tmp_path, caplog, capsys):
    """Heads that always said bump with certainty, against a full model that says pull, decided every
    event after 4 frames with no warning."""
    import logging
    from types import SimpleNamespace

    from runtime.commands.inspect_cli import main as inspect_main
    from runtime.config import config_from_dict
    from runtime.health import Health
    from runtime.model import load_model
    from runtime.model_serving import ModelSlot

    path = tmp_path / "lying.onnx"
    path.write_bytes(_tiny_with_lying_heads([4, 8]))
    model = load_model(path)
    assert model.early is None  # the full model decides every event
    assert "early heads at 4, 8 frames disabled" in model.early_note
    labels, _ = model.run(np.full((1, 15, 234), 500.0, np.float32))
    assert model.meta.classes[int(labels[0])] == "pull"
    cfg = config_from_dict({"device": {"url": "sim://"}, "model": {"folder": str(tmp_path)}})
    health = Health()
    with caplog.at_level(logging.WARNING, logger="handover"):
        ModelSlot(cfg, health, serve=lambda _: None, announce=lambda _: None).use(model)
    assert [r.getMessage() for r in caplog.records if "disabled" in r.getMessage()] == [model.early_note]
    assert health.last_error == model.early_note
    assert inspect_main(SimpleNamespace(model=str(path), json=False)) in (0, None)
    assert "warning: " + model.early_note in capsys.readouterr().out
    honest = tmp_path / "honest.onnx"
    honest.write_bytes(_tiny_with_heads(15, [4, 8]))
    kept = load_model(honest)
    assert kept.early.points == (4, 8) and kept.early_note is None


def test_a_subject_too_small_for_a_training_part_skips_early_decisions_naming_it():
    """One trial naming another subject (s9: a trial's subject is its own) made train fail with 'need
    samples of at least 2 classes', naming no one: leaving out s1 and s2 trains on s9's one pull alone.
    The early decisions are skipped with a line naming the subjects; the model still trains."""
    from types import SimpleNamespace

    from trainer.pipeline import fit_early_heads

    y = np.asarray(["pull", "push", "hold", "bump"] * 4 + ["pull"])
    groups = np.asarray(["s1"] * 8 + ["s2"] * 8 + ["s9"])
    said = []
    heads, ev = fit_early_heads(SimpleNamespace(early="on", T=15), SimpleNamespace(groups=groups, y=y), None,
                                said.append)
    assert heads is None and ev["skipped"].startswith("leaving out s1 and s2 would train on s9 alone (1 case, all pull)")
    assert said == [f"early decisions skipped: {ev['skipped']}"]


def test_a_rule_fitted_once_searches_c_once_per_point(early_model, monkeypatch):
    """The demo's stream model searched C again for every held-out fold of every head: most of its training time."""
    from trainer import classifier, early

    _, ds, _, _ = early_model
    searches = []
    real = classifier.choose_svm_params
    monkeypatch.setattr(classifier, "choose_svm_params",
                        lambda f, y, kernel, C=None, *a, **k: searches.append(C is None) or real(f, y, kernel, C, *a, **k))
    make = early.head_factory(ds.pad_sizes)
    fits = early.Fits(ds.X, ds.y, ds.groups, (4, 8), make, make)
    fits.searched_once = True
    heads = early.fit_early(ds.X, ds.y, ds.groups, make, make, (4, 8), fits=fits)
    groups = sorted(set(ds.groups.tolist()))
    assert sum(searches) == 3  # one search per point and the full window; each fold takes their C
    for g in groups:
        fold = fits.models(frozenset({g}))
        assert [m.svm_.C for m in fold] == [m.svm_.C for m in fits.models(frozenset())]
    assert heads.spec.points == (4, 8) and len(heads.models) == 2


def test_disabling_one_head_keeps_the_classes_training_allows_early(tmp_path):
    """The warm-up rebuilt the spec of the heads it kept without ``classes``: a model that keeps bump for
    the full window then let every class come early from its remaining heads."""
    import onnx

    from runtime.model import load_model

    proto = onnx.load_from_string(_tiny_with_lying_heads([4]))
    honest = onnx.load_from_string(_tiny_with_heads(15, [8]))
    proto.graph.node.extend(n for n in honest.graph.node if n.output[0].endswith("_at_8"))
    proto.graph.output.extend(o for o in honest.graph.output if o.name.endswith("_at_8"))
    meta = json.loads(proto.metadata_props[0].value)
    meta["early"].update(points=[4, 8], calibration=[[1.0, 0.0]] * 2, classes=["pull", "bump"])
    proto.metadata_props[0].value = json.dumps(meta)
    path = tmp_path / "half.onnx"
    path.write_bytes(proto.SerializeToString())
    model = load_model(path)
    assert "early heads at 4 frames disabled" in model.early_note
    assert model.early.points == (8,) and model.early.classes == ("pull", "bump")


def test_early_classes_the_model_does_not_have_are_refused_in_one_line(tmp_path):
    """A broken export naming ``Pull`` (or a class of another model) let no class come early, silently:
    names are matched against the model's classes, so a name it lacks is refused like other bad metadata."""
    import onnx

    from runtime.model import ModelContractError, load_model

    proto = onnx.load_from_string(_tiny_with_heads(15, [4, 8]))
    meta = json.loads(proto.metadata_props[0].value)
    meta["early"]["classes"] = ["Pull", "push"]
    proto.metadata_props[0].value = json.dumps(meta)
    path = tmp_path / "typo.onnx"
    path.write_bytes(proto.SerializeToString())
    with pytest.raises(ModelContractError, match=r"early.classes names 'Pull', not a class of the model") as info:
        load_model(path)
    assert "\n" not in str(info.value)
    with pytest.raises(EarlySpecError, match="not a class of the model"):
        EarlySpec.from_meta({**SPEC, "classes": ["dormant"]}, T=15, class_names=("pull", "push"))


def _tiny_with_sure_heads(points: list[int], sure: str, early_classes: list[str] | None = None) -> bytes:
    """A tiny stream model (the actions and dormant; its full answer is pull) whose early heads say
    ``sure`` with certainty, always."""
    import onnx
    from onnx import TensorProto, helper

    from tests.tiny_models import CLASSES, tiny_model_bytes

    classes = (*CLASSES, "dormant")
    proto = onnx.load_from_string(tiny_model_bytes(classes=classes, dormant_class="dormant"))
    proto.graph.initializer.append(helper.make_tensor("certain", TensorProto.FLOAT, [len(classes)],
                                                      [100.0 * (c == sure) for c in classes]))
    for p in points:
        proto.graph.node.extend([helper.make_node("Add", ["scores", "certain"], [f"scores_at_{p}"]),
                                 helper.make_node("ArgMax", [f"scores_at_{p}"], [f"label_at_{p}"], axis=1, keepdims=0)])
        proto.graph.output.extend([helper.make_tensor_value_info(f"label_at_{p}", TensorProto.INT64, ["N"]),
                                   helper.make_tensor_value_info(f"scores_at_{p}", TensorProto.FLOAT,
                                                                 ["N", len(classes)])])
    meta = json.loads(proto.metadata_props[0].value)
    meta["early"] = {"points": points, "calibration": [[1.0, 0.0]] * len(points), "threshold": 0.9, "agree": False,
                     **({} if early_classes is None else {"classes": early_classes})}
    proto.metadata_props[0].value = json.dumps(meta)
    return proto.SerializeToString()


def test_heads_sure_of_a_class_never_reported_early_are_kept(tmp_path):
    """The warm-up disabled a head sure of dormant on every probe window (a stream model's 4-frame head says
    dormant on most of them): a dormant answer, or one of a class training keeps to T, is never reported
    early, so such a head decides no event; the check is about the answers the rule could report."""
    from runtime.model import load_model

    for name, sure, early_classes in (("dormant", "dormant", None), ("kept", "bump", ["pull", "push"])):
        path = tmp_path / f"{name}.onnx"
        path.write_bytes(_tiny_with_sure_heads([4, 8], sure, early_classes))
        model = load_model(path)
        assert model.early_note is None and model.early.points == (4, 8), name
    path = tmp_path / "bump.onnx"
    path.write_bytes(_tiny_with_sure_heads([4, 8], "bump"))
    assert load_model(path).early is None  # a head sure of a class it may report still is disabled
