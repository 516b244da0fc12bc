"""Simulated labs: lab A is the simulator as it was (bytes pinned); lab B differs in each documented way."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from firmware_io.sim import constants as K
from firmware_io.sim import demo_script, simulate_protocol, simulate_session
from firmware_io.sim.idle import idle_rng, plan_stretch, render_hold, simulate_idle
from firmware_io.sim.lab import LABS, UnknownLab, get_lab, lab_of
from firmware_io.sim.paper_protocol import hand_sensor
from firmware_io.sim.scripted_subject import ScriptedSubject
from firmware_io.sim.streams import stream
from firmware_io.transports.base import ParsedURL, TransportError
from firmware_io.transports.emulated import SimTransport, SubjectTransport

B = LABS["B"]


def test_lab_a_bytes_are_the_simulators_before_labs():
    """Taken on the simulator before labs existed (seed 7): the protocol and session bytes, the idle stretch and
    stream fingerprints."""
    h = hashlib.sha256()
    for r in simulate_protocol(seed=7, n_subjects=2, runs=1, poses=["down"]):
        h.update(r.frames.tobytes())
        h.update(r.timestamps.tobytes())
    s = simulate_session(demo_script(4, seed=7), seed=7)
    h.update(s.frames.tobytes())
    h.update(s.timestamps.tobytes())
    assert h.hexdigest() == "9ab235903e3fdf68fe784d7f8e5d234be60392c0712c958041a116103d999c9e"
    rng = idle_rng(7, "recorded", 1)
    hold = render_hold(plan_stretch(rng, "arm_move", 6.0), hand_sensor(7), rng)
    idle = simulate_idle(30.0, seed=7).frames
    # the idle's transcendental functions round a count differently on another CPU's SIMD (an Intel Xeon
    # against the AMD EPYC the bytes were pinned on): its fingerprint, to a count here and there
    for frames, (total, touched, top) in ((hold, (604878, 4219, 553)), (idle, (3705174, 22326, 534))):
        assert frames.dtype == np.uint16 and abs(int(frames.sum(dtype=np.int64)) - total) <= 1e-4 * total
        assert abs(int(np.count_nonzero(frames)) - touched) <= 0.002 * touched and abs(int(frames.max()) - top) <= 2
    assert hold.shape == (191, 486) and idle.shape == (951, 486)
    assert "lab" not in s.meta  # A's files say what they said before


def test_lab_b_hand_gain_noise_dead_and_hot_taxels():
    a, b = hand_sensor(3), hand_sensor(3, lab="B")
    layout = a.layout
    for pad in range(layout.n_matrices):
        cols = layout.matrix_slice(pad)
        assert np.mean(b.gain[cols]) / np.mean(a.gain[cols]) == pytest.approx(B.pad_gain[pad], rel=0.05)
    assert b.noise_sd == B.noise_sd > a.noise_sd == K.IDLE_NOISE_SD
    assert (~b.mask).sum() - (~a.mask).sum() == B.dead_taxels
    assert (b.idle >= K.THRESHOLD).sum() == B.hot_taxels and (a.idle >= K.THRESHOLD).sum() == 0
    assert np.median(b.idle[b.idle < K.THRESHOLD]) > np.median(a.idle) + 5  # the higher floor


@pytest.fixture(scope="module")
def lab_b() -> list:
    return simulate_protocol(seed=2, n_subjects=1, runs=1, poses=["down"], lab="B")


def test_lab_b_dead_taxels_are_dead_and_hot_ones_flicker(lab_b):
    sensor = hand_sensor(2, lab="B")
    dead = ~sensor.mask & sensor.layout.static_mask()
    frames = np.concatenate([r.frames for r in lab_b])
    assert dead.sum() == B.dead_taxels and not frames[:, dead].any()
    hot = sensor.idle >= K.THRESHOLD
    assert 0.1 < np.mean(frames[:, hot] > 0) < 0.9


def test_lab_b_has_its_objects_its_people_and_says_its_lab(lab_b):
    rec = lab_b[0]
    assert {t.object for t in rec.trials} == set(B.objects) and {"bottle", "sponge"} <= set(B.objects)
    assert rec.meta["lab"] == "B" and lab_of(rec.meta) == "B"
    # another lab's person: its own stream, times the lab's strength and speed
    rng = stream(2, "subject", "s1", "lab", "B")
    assert rec.meta["subject_profile"]["strength"] == round(float(rng.lognormal(0.0, 0.25)) * B.strength, 4)
    assert rec.meta["subject_profile"]["speed"] == round(float(rng.lognormal(0.0, 0.2)) * B.speed, 4)
    with pytest.raises(ValueError, match="bottle"):
        simulate_protocol(seed=2, n_subjects=1, runs=1, objects=["bottle"])  # not lab A's


def test_lab_b_grips_firmer():
    from firmware_io.sim.scenario import OBJECT_MODELS, POSE_MODELS, make_subject, make_trial

    person = make_subject("x", np.random.default_rng(0))
    setups = [make_trial(person, OBJECT_MODELS["ball"], POSE_MODELS["up"], "hold", 3.0, np.random.default_rng(1),
                         grip=g) for g in (1.0, B.grip)]
    d_n = -0.2 * OBJECT_MODELS["ball"].mass_kg * K.GRAVITY  # the "up" pose's share, the same in both
    np.testing.assert_allclose((setups[1].grasp_force - d_n) / (setups[0].grasp_force - d_n), B.grip)


def test_lab_b_session_plays_lab_b():
    script = demo_script(6, seed=1, objects=B.objects)
    a = simulate_session(demo_script(6, seed=1), seed=1)
    b = simulate_session(script, seed=1, lab="B")
    assert b.meta["lab"] == "B" and {e.object for e in script} <= set(B.objects)
    assert np.percentile(b.frames[b.frames > 0], 95) > 2 * np.percentile(a.frames[a.frames > 0], 95)


def test_url_option_lab():
    assert SubjectTransport.url_settings(ParsedURL("subject://?seed=3&lab=B"), {})["lab"] is B
    assert SubjectTransport.url_settings(ParsedURL("subject://?seed=3&lab=b"), {})["lab"] is B
    assert SubjectTransport.url_settings(ParsedURL("subject://?seed=3"), {})["lab"] is LABS["A"]
    assert SimTransport.url_settings(ParsedURL("sim://?lab=B&events=2"), {})["lab"] == "B"
    for url in ("subject://?lab=C", "sim://?lab=Z"):
        with pytest.raises(TransportError, match=r"unknown lab 'C'|unknown lab 'Z'") as err:
            (SubjectTransport if url.startswith("subject") else SimTransport).url_settings(ParsedURL(url), {})
        assert "A (" in str(err.value) and "B (" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(UnknownLab):
        get_lab("default")


def test_scripted_subject_of_lab_b_plays_its_objects_and_says_its_lab():
    subject = ScriptedSubject.from_url("subject://?seed=1&lab=B&speed=max")
    assert subject.meta == {"synthetic": True, "lab": "B"}
    assert ScriptedSubject(seed=1).meta == {"synthetic": True}
    assert [B.object_for(o) for o in ("ball", "cylinder", "plank", "sponge")] == ["ball", "bottle", "sponge", "sponge"]


def test_a_recording_of_a_lab_b_subject_says_its_lab(tmp_path):
    from firmware_io.recordings.recording import Recording
    from runtime.cli import main as handover

    code = handover(["record", "--device", "subject://?seed=3&lab=B&speed=max", "--subject", "s1", "--out", str(tmp_path),
                     "--poses", "down", "--objects", "cylinder", "--actions", "bump", "--runs", "1", "--trial-seconds",
                     "2", "--gap", "0", "--countdown", "0", "--quiet", "--idle-minutes", "0", "--auto"])
    assert code == 0
    rec = Recording.load(tmp_path / "subject_s1.hrec")
    assert rec.meta["lab"] == "B" and rec.meta["synthetic"] is True
    played = rec.trials[0].extra["scripted_subject"]
    assert rec.trials[0].object == "cylinder" and played["object"] == "bottle" and played["lab"] == "B"


def test_demo_plays_lab_bs_session_to_a_given_model(tmp_path, capsys):
    from runtime.cli import main as handover
    from tests.tiny_models import tiny_model_bytes
    from trainer.commands.demo_cli import scripted_session

    _, script, session = scripted_session(0, 4, "B")
    assert session.meta["lab"] == "B" and {e.object for e in script} <= set(B.objects)
    model = tmp_path / "tiny.onnx"
    model.write_bytes(tiny_model_bytes())
    code = handover(["demo", "--lab", "B", "--model", str(model), "--events", "4", "--speed", "max", "--json",
                     "--out", str(tmp_path / "demo")])
    out = capsys.readouterr().out
    assert code == 0
    summary = json.loads(out)  # stdout is the JSON alone
    assert summary["lab"] == "B" and summary["events_expected"] == 4 and summary["synthetic"] is True


@pytest.mark.parametrize("command", [["demo"], ["simulate", "--out", "x"], ["emulate", "--pty"]])
def test_an_unknown_lab_is_one_line_naming_the_labs(command, capsys):
    from runtime.cli import main as handover

    with pytest.raises(SystemExit) as exit_:
        handover([*command, "--lab", "C"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "unknown lab 'C'" in err and "A (" in err and "B (" in err


def test_simulate_writes_lab_bs_protocol(tmp_path):
    from firmware_io.recordings.recording import Recording
    from runtime.cli import main as handover

    assert handover(["simulate", "--out", str(tmp_path), "--lab", "b", "--subjects", "1", "--runs", "1"]) == 0
    rec = Recording.load(tmp_path / "subject_s1.hrec")
    assert rec.meta["lab"] == "B" and {t.object for t in rec.trials} == set(B.objects)


def test_the_mixed_labs_line_names_each_labs_files():
    from types import SimpleNamespace as R

    from trainer.data_warnings import lab_line

    recs = [R(meta={"synthetic": True}), R(meta={"synthetic": True, "lab": "B"}), R(meta={"source": "real"})]
    names = ["d/subject_s1.hrec", "d/subject_s2.hrec", "d/real.dsa"]
    assert lab_line(recs, names).startswith("the recordings come from 2 simulated labs (lab A: subject_s1.hrec; "
                                            "lab B: subject_s2.hrec): ")
    assert lab_line(recs[:1] + recs[2:], names[:1] + names[2:]) is None  # a real recording is no lab
    many = [R(meta={"synthetic": True})] * 5 + recs[1:2]
    assert "lab A: a0, a1, a2 and 2 more; lab B: b" in lab_line(many, [f"a{i}" for i in range(5)] + ["b"])


@pytest.mark.slow
def test_train_says_which_labs_its_recordings_come_from_and_trains(tmp_path, capsys):
    """A lab-B recording among lab-A ones: one line naming the files' labs; the model is still trained."""
    from runtime.cli import main as handover
    from trainer.data_warnings import lab_line

    data = tmp_path / "data"
    for name, seed, lab in (("s1", 0, "A"), ("s2", 1, "A"), ("s3", 2, "B")):
        rec = simulate_protocol(seed=seed, n_subjects=1, runs=1, poses=["down"], lab=lab)[0]
        rec.meta["subject"] = name
        rec.save(data / f"subject_{name}.hrec")
    code = handover(["train", "--data", str(data), "--out", str(tmp_path / "r"), "--no-sweep", "--repeats", "2",
                     "--no-replay", "--early", "off", "--no-onnx", "--quiet"])
    err = capsys.readouterr().err
    assert code == 0, err
    line = next(x for x in err.splitlines() if "simulated labs" in x)
    assert "lab A: subject_s1.hrec, subject_s2.hrec; lab B: subject_s3.hrec" in line
    one_lab = simulate_protocol(seed=0, n_subjects=2, runs=1, poses=["down"], objects=["ball"])
    assert lab_line(one_lab, ["a", "b"]) is None
