"""Recording files: round trip, atomic writes, and one clear error for every kind of bad file."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pytest

import firmware_io.recordings.recording as recording_module
from firmware_io.layout import SensorLayout
from firmware_io.recordings.recording import ACTIONS, Recording, RecordingError, Trial, find_recordings
from tests.memory import PEAK_MB

ROOT = Path(__file__).resolve().parents[1]


def make_recording(n_frames: int = 120, seed: int = 0, layout: SensorLayout | None = None) -> Recording:
    layout = layout or SensorLayout.sdh2()
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 4096, size=(n_frames, layout.n_taxels), dtype=np.uint16)
    stamps = np.cumsum(rng.uniform(0.025, 0.038, n_frames))
    trials = [
        Trial("s1", "ball", "down", "pull", 1, 0, 44, {"onset": 12}),
        Trial("s1", "plank", "up", "bump", 2, 45, n_frames - 1),
    ]
    return Recording(layout, frames, stamps, trials, {"source": "synthetic test data", "seed": seed})


def assert_same(a: Recording, b: Recording) -> None:
    assert np.array_equal(a.frames, b.frames) and a.frames.dtype == b.frames.dtype == np.uint16
    assert np.array_equal(a.timestamps, b.timestamps) and b.timestamps.dtype == np.float64
    assert a.trials == b.trials
    assert [t.extra for t in a.trials] == [t.extra for t in b.trials]
    assert a.layout == b.layout
    assert np.array_equal(a.layout.static_mask(), b.layout.static_mask())
    assert a.meta == b.meta


# -- round trip ------------------------------------------------------------------------------


def test_round_trip(tmp_path):
    rec = make_recording()
    path = rec.save(tmp_path / "subject_s1.hrec")
    back = Recording.load(path)
    assert_same(rec, back)
    assert back.trials[0].extra == {"onset": 12}
    assert back.trials[1].action in ACTIONS
    assert back.trial_frames(back.trials[1])[0].shape == (rec.n_frames - 45, 486)
    assert find_recordings(tmp_path) == [path]


def test_round_trip_of_a_subset_layout_and_empty_recording(tmp_path):
    layout = SensorLayout.sdh2().subset("distal")
    rec = Recording(layout, np.zeros((0, layout.n_taxels), np.uint16), np.zeros(0))
    assert_same(rec, Recording.load(rec.save(tmp_path / "empty.hrec")))
    small = make_recording(n_frames=60, layout=layout)
    assert_same(small, Recording.load(small.save(tmp_path / "distal.hrec")))


def test_save_replaces_an_existing_file(tmp_path):
    path = tmp_path / "r.hrec"
    make_recording(seed=1).save(path)
    newer = make_recording(seed=2)
    newer.save(path)
    assert_same(newer, Recording.load(path))
    assert sorted(os.listdir(tmp_path)) == ["r.hrec"]


# -- atomic writes ---------------------------------------------------------------------------


def test_failure_during_write_keeps_old_file_and_leaves_no_temp(tmp_path, monkeypatch):
    path = tmp_path / "r.hrec"
    old = make_recording(seed=1)
    old.save(path)
    calls = []

    def failing_npy_bytes(arr):
        calls.append(arr.shape)
        if len(calls) == 2:  # frames written, timestamps fail: the temp file is half written
            raise OSError("disk full (simulated)")
        return real(arr)

    real = recording_module._npy_bytes
    monkeypatch.setattr(recording_module, "_npy_bytes", failing_npy_bytes)
    with pytest.raises(OSError, match="disk full"):
        make_recording(seed=2).save(path)
    assert sorted(os.listdir(tmp_path)) == ["r.hrec"]
    assert_same(old, Recording.load(path))

    calls.clear()
    with pytest.raises(OSError):
        make_recording(seed=3).save(tmp_path / "new.hrec")
    assert sorted(os.listdir(tmp_path)) == ["r.hrec"]


_KILL_CHILD = textwrap.dedent(
    """
    import os, signal, sys, zipfile
    sys.path.insert(0, {root!r})
    import numpy as np
    from firmware_io.layout import SensorLayout
    from firmware_io.recordings.recording import Recording

    real_writestr = zipfile.ZipFile.writestr

    def writestr(self, name, data, *a, **kw):
        if getattr(name, "filename", name) == "frames.npy":  # write half of the frames, flush, then die
            real_writestr(self, name, data[: len(data) // 2])
            self.fp.flush()
            os.kill(os.getpid(), signal.SIGKILL)
        return real_writestr(self, name, data, *a, **kw)

    zipfile.ZipFile.writestr = writestr
    layout = SensorLayout.sdh2()
    rec = Recording(layout, np.full((400, layout.n_taxels), 7, np.uint16), np.arange(400) / 32.0)
    rec.save(sys.argv[1])
    """
)


@pytest.mark.parametrize("had_old_file", [True, False])
def test_sigkill_mid_write_never_leaves_a_half_file_under_the_final_name(tmp_path, had_old_file):
    path = tmp_path / "r.hrec"
    old = make_recording(seed=5)
    if had_old_file:
        old.save(path)
    script = tmp_path / "child.py"
    script.write_text(_KILL_CHILD.format(root=str(ROOT)))
    proc = subprocess.run([sys.executable, str(script), str(path)], capture_output=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()
    visible = sorted(p for p in os.listdir(tmp_path) if not p.startswith("."))
    if had_old_file:
        assert visible == ["child.py", "r.hrec"]
        assert_same(old, Recording.load(path))
    else:
        assert visible == ["child.py"]
    # a killed writer can leave its hidden temp file, never one that a reader would pick up
    leftovers = [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert all(p.suffix == ".tmp" for p in leftovers)
    assert find_recordings(tmp_path) == ([path] if had_old_file else [])


# -- bad files -------------------------------------------------------------------------------


@pytest.fixture
def saved(tmp_path) -> Path:
    return make_recording(n_frames=200).save(tmp_path / "good.hrec")


def assert_refused(path: Path, match: str | None = None) -> None:
    with pytest.raises(RecordingError) as info:
        Recording.load(path)
    message = str(info.value)
    assert str(path) in message
    assert "\n" not in message
    if match:
        assert match in message


@pytest.mark.parametrize("fraction", [0.0, 0.1, 0.5, 0.9, 0.999])
def test_truncated_file(saved, fraction):
    data = saved.read_bytes()
    bad = saved.with_name("truncated.hrec")
    bad.write_bytes(data[: int(len(data) * fraction)])
    assert_refused(bad)


def test_flipped_byte_in_frame_data_is_detected(saved):
    data = bytearray(saved.read_bytes())
    with zipfile.ZipFile(saved) as zf:
        info = zf.getinfo("frames.npy")
    # the member's data starts after its 30-byte local header, name and extra field
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    data[start + info.file_size // 2] ^= 0x10
    bad = saved.with_name("flipped.hrec")
    bad.write_bytes(bytes(data))
    assert_refused(bad)


def test_flipped_bytes_anywhere_never_give_wrong_data(saved):
    original = Recording.load(saved)
    data = saved.read_bytes()
    bad = saved.with_name("flipped.hrec")
    for pos in np.linspace(0, len(data) - 1, 61).astype(int):
        flipped = bytearray(data)
        flipped[pos] ^= 0xFF
        bad.write_bytes(bytes(flipped))
        try:
            back = Recording.load(bad)
        except RecordingError as exc:
            assert str(bad) in str(exc)
            continue
        assert_same(original, back)  # a flip in ZIP bookkeeping that does not touch the data


def test_foreign_files(tmp_path):
    text = tmp_path / "notes.hrec"
    text.write_text("hello, this is not a recording\n")
    assert_refused(text)

    plain_zip = tmp_path / "plain.hrec"
    with zipfile.ZipFile(plain_zip, "w") as zf:
        zf.writestr("readme.txt", "just a zip")
    assert_refused(plain_zip, "not a handover recording")

    npz = tmp_path / "random.npz"
    np.savez(npz, a=np.random.default_rng(0).normal(size=10))
    assert_refused(npz, "not a handover recording")

    other_json = tmp_path / "other.hrec"
    with zipfile.ZipFile(other_json, "w") as zf:
        zf.writestr("header.json", json.dumps({"format": "something-else", "version": 1}))
    assert_refused(other_json, "not a handover recording")

    for not_an_object in ([], "text", 3):
        odd = tmp_path / "odd.hrec"
        with zipfile.ZipFile(odd, "w") as zf:
            zf.writestr("header.json", json.dumps(not_an_object))
        assert_refused(odd, "not a handover recording")

    assert_refused(tmp_path / "missing.hrec", "no such file")
    assert_refused(tmp_path, "folder")


def test_saved_file_follows_the_umask_not_mkstemps_0600(tmp_path):
    old = os.umask(0o022)
    try:
        path = make_recording().save(tmp_path / "r.hrec")
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o644


def _rewrite_header(src: Path, dst: Path, **changes) -> None:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for name in zin.namelist():
            data = zin.read(name)
            if name == "header.json":
                header = json.loads(data)
                header.update(changes)
                data = json.dumps(header).encode()
            zout.writestr(name, data)


def test_wrong_version(saved):
    bad = saved.with_name("future.hrec")
    _rewrite_header(saved, bad, version=99)
    assert_refused(bad, "version 99")


def test_header_that_disagrees_with_the_data(saved):
    bad = saved.with_name("liar.hrec")
    _rewrite_header(saved, bad, n_frames=5)
    assert_refused(bad)
    trials = saved.with_name("trials.hrec")
    _rewrite_header(
        saved,
        trials,
        trials=[
            {"subject": "s1", "object": "ball", "pose": "up", "action": "pull", "run": 1, "first": 0, "last": 10_000}
        ],
    )
    assert_refused(trials, "trial 0")


@pytest.mark.parametrize(("change", "match"), [
    ({"run": 10**30}, "trial 0: run 1000000000000000000000000000000 outside 0..2147483647"),
    ({"subject": "s" * (4 << 20)}, "trial 0: subject must be a name of 1 to 64 printable characters, got 'sss"),
    ({"action": "x" * 65}, "trial 0: action must be a name"),
    ({"subject": "s1\x1b[2J"}, "trial 0: subject must be a name of 1 to 64 printable characters, got 's1\\x1b[2J'"),
])
def test_trial_numbers_and_names_training_cannot_hold_are_refused_at_load(saved, change, match):
    """A run of 10**30 ended training in an OverflowError; a 4 MB subject id multiplied its peak memory by 4.5;
    an ESC in a subject id went raw into train's report.md and the terminal."""
    bad = saved.with_name("names.hrec")
    trial = {"subject": "s1", "object": "ball", "pose": "up", "action": "pull", "run": 1, "first": 0, "last": 10}
    _rewrite_header(saved, bad, trials=[{**trial, **change}])
    assert_refused(bad, match)


@pytest.mark.parametrize(("meta", "match"), [
    ({"sources": ["open", "quiet"], "source_codes": [0] * 5}, "meta.source_codes must hold one code per frame (200)"),
    ({"sources": ["open", "quiet"], "source_codes": [7] * 200}, "meta.source_codes"),
    ({"sources": 42, "source_codes": [0] * 200}, "meta.sources must be a list"),
    ({"arm_marks": "garbage"}, "meta.arm_marks must be a list"),
    ({"arm_marks": [[10**12, 1]]}, "meta.arm_marks: frame 1000000000000"),
])
def test_idle_codes_and_arm_marks_that_do_not_fit_the_frames_are_refused_at_load(saved, meta, match):
    """Training and replay index frames by these keys: a damaged file is one line naming it, not an
    IndexError deep in training."""
    bad = saved.with_name("idle.hrec")
    _rewrite_header(saved, bad, meta=meta)
    assert_refused(bad, match)


def test_missing_member(saved):
    bad = saved.with_name("partial.hrec")
    with zipfile.ZipFile(saved) as zin, zipfile.ZipFile(bad, "w") as zout:
        for name in ("header.json", "frames.npy"):
            zout.writestr(name, zin.read(name))
    assert_refused(bad, "timestamps.npy")


# -- construction ----------------------------------------------------------------------------


def test_inconsistent_data_is_refused_at_construction():
    layout = SensorLayout.sdh2()
    ok_frames = np.zeros((4, 486), np.uint16)
    ok_t = np.array([0.0, 0.03, 0.06, 0.09])
    Recording(layout, ok_frames, ok_t)
    with pytest.raises(RecordingError, match="taxels"):
        Recording(layout, np.zeros((4, 485), np.uint16), ok_t)
    with pytest.raises(RecordingError, match="2-D"):
        Recording(layout, np.zeros(486, np.uint16), ok_t[:1])
    with pytest.raises(RecordingError, match="timestamps"):
        Recording(layout, ok_frames, ok_t[:3])
    with pytest.raises(RecordingError, match="increasing"):
        Recording(layout, ok_frames, np.array([0.0, 0.03, 0.03, 0.09]))
    with pytest.raises(RecordingError, match="increasing"):
        Recording(layout, ok_frames, np.array([0.0, 0.03, 0.02, 0.09]))
    with pytest.raises(RecordingError, match="NaN"):
        Recording(layout, ok_frames[:1], np.array([np.nan]))
    with pytest.raises(RecordingError, match="trial 0"):
        Recording(layout, ok_frames, ok_t, [Trial("s1", "ball", "up", "push", 1, 2, 4)])
    with pytest.raises(RecordingError, match="trial 0"):
        Recording(layout, ok_frames, ok_t, [Trial("s1", "ball", "up", "push", 1, 3, 2)])


def test_save_refuses_a_recording_made_inconsistent_later(tmp_path):
    rec = make_recording()
    rec.timestamps = rec.timestamps[::-1].copy()
    with pytest.raises(RecordingError, match="not saved"):
        rec.save(tmp_path / "x.hrec")
    assert not (tmp_path / "x.hrec").exists()


def test_concatenate_builds_trials():
    layout = SensorLayout.sdh2()
    seg = np.zeros((10, 486), np.uint16)
    fields = {"subject": "s2", "object": "cylinder", "pose": "horizontal", "action": "hold", "run": 3}
    rec = Recording.concatenate(layout, [(seg, np.arange(10) / 32, fields), (seg, 1 + np.arange(10) / 32, None)])
    assert rec.n_frames == 20
    assert [(t.first, t.last) for t in rec.trials] == [(0, 9)]
    assert rec.sample_interval() == pytest.approx(1 / 32)


def test_a_compressed_recording_is_refused_before_it_inflates(tmp_path):
    """2.6 MB deflated inflated to 1.07 GB of frames (within the per-file limit); six of them killed a
    training run. Our writer never compresses, so a compressed member is refused by name, quickly, in a
    child whose peak memory stays far below the frames it declares (256 MiB here)."""
    layout = SensorLayout.sdh2()
    n = (256 << 20) // (2 * layout.n_taxels)
    header = {"format": "handover-recording", "version": 1, "n_frames": n, "n_taxels": layout.n_taxels,
              "layout": layout.to_dict(), "trials": [], "meta": {}}
    path = tmp_path / "subject_zip.hrec"
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("header.json", json.dumps(header))
        with zf.open("frames.npy", "w", force_zip64=True) as fh:
            np.lib.format.write_array_header_1_0(fh, {"descr": "<u2", "fortran_order": False,
                                                      "shape": (n, layout.n_taxels)})
            for at in range(0, n * layout.n_taxels * 2, 1 << 20):
                fh.write(bytes(min(1 << 20, n * layout.n_taxels * 2 - at)))
        zf.writestr("timestamps.npy", recording_module._npy_bytes(np.arange(n, dtype=np.float64)))
    assert path.stat().st_size < 8 << 20
    code = ("import json, sys, time\nfrom firmware_io.recordings.recording import Recording, RecordingError\n"
            "t = time.process_time()\ntry:\n    Recording.load(sys.argv[1]); said = 'loaded'\n"
            "except RecordingError as exc:\n    said = str(exc)\n"
            "print(json.dumps({'said': said, 's': time.process_time() - t,"
            " 'mb': " + PEAK_MB + "}))")
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, cwd=ROOT,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=60, check=True)
    got = json.loads(done.stdout)
    assert got["said"].startswith(f"{path}: refused: member ") and " is compressed; " in got["said"], got
    assert got["s"] < 5 and got["mb"] < 500, got


def test_a_compressed_header_is_said_to_be_compressed_not_invalid_json(tmp_path):
    """It read "member header.json is not valid JSON (member header.json is compressed...)"."""
    path = tmp_path / "subject_s1.hrec"
    make_recording().save(path)
    with zipfile.ZipFile(path) as zf:
        members = {name: zf.read(name) for name in zf.namelist()}
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data, compress_type=zipfile.ZIP_DEFLATED if name == "header.json" else None)
    with pytest.raises(RecordingError) as err:
        Recording.load(path)
    assert "member header.json is compressed; " in str(err.value) and "JSON" not in str(err.value), err.value
