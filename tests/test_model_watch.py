"""The model folder watcher: complete files only, trusted files only, broken ones refused."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from runtime.config import config_from_dict
from runtime.model import load_model
from runtime.model_watch import ModelWatcher, is_candidate_name
from runtime.scene import scene_problem
from tests.tiny_models import tiny_model_bytes, write_model

pytest.importorskip("onnx")


def _watcher(folder: Path, **cfg) -> ModelWatcher:
    config = config_from_dict(cfg)
    return ModelWatcher(folder, loader=lambda p: load_model(p, warm_up=False),
                        check=lambda m: scene_problem(m, config, None), poll_interval=0.05)


def test_names():
    assert is_candidate_name("m.onnx")
    for name in (".m.onnx", "m.onnx.tmp", "m.onnx.part", "m.tmp", "m.txt", ".m.onnx.tmp"):
        assert not is_candidate_name(name), name


def test_startup_serves_the_newest_valid(tmp_path):
    now = time.time()
    write_model(tmp_path, "old.onnx", tiny_model_bytes(tag="old"), mtime=now - 100)
    write_model(tmp_path, "new.onnx", tiny_model_bytes(tag="new"), mtime=now - 50)
    (tmp_path / "newest-broken.onnx").write_bytes(b"not a model")
    os.utime(tmp_path / "newest-broken.onnx", (now - 20, now - 20))  # settled: not a copy in progress
    w = _watcher(tmp_path)
    model = w.poll(require_stable=False)
    assert model is not None and model.path.name == "new.onnx"
    assert [r.path.name for r in w.rejections] == ["newest-broken.onnx"]


def test_removing_the_serving_file_serves_the_newest_valid_file_left_also_one_that_served_before(tmp_path):
    """docs/GUIDE.md's rollback, remove the newer file: the files this watcher once served and then
    replaced were never weighed again, so the folder was taken as holding none that can serve."""
    now = time.time() - 1000
    write_model(tmp_path, "a.onnx", tiny_model_bytes(tag="a"), mtime=now)
    w = _watcher(tmp_path)
    assert w.poll(require_stable=False).path.name == "a.onnx"
    for k, (name, data) in enumerate([("b.onnx", tiny_model_bytes(tag="b")), ("broken.onnx", b"not a model"),
                                      ("a2.onnx", tiny_model_bytes(tag="a2")), ("b2.onnx", tiny_model_bytes(tag="b2"))]):
        write_model(tmp_path, name, data, mtime=now + 8 * (k + 1))
        w.poll(), w.poll()
    assert w.current.path.name == "b2.onnx"
    (tmp_path / "b2.onnx").unlink()
    w.poll()
    assert w.take().path.name == "a2.onnx" and not w.withdrawn
    (tmp_path / "a2.onnx").unlink()
    w.poll()
    assert w.take().path.name == "b.onnx"


def test_a_serving_file_broken_in_place_is_withdrawn_once_it_is_weighed(tmp_path):
    """Truncated (or a bad file copied over it) instead of removed: the poll that sees the change cannot weigh
    it yet (not stable), so the withdrawal waits for the poll that can; the folder then serves none."""
    path = write_model(tmp_path, "m.onnx", tiny_model_bytes(), mtime=time.time() - 1000)
    w = _watcher(tmp_path)
    assert w.poll(require_stable=False).path.name == "m.onnx" and w.take() is not None
    with open(path, "r+b") as f:
        f.truncate(path.stat().st_size // 2)
    for _ in range(4):
        w.poll()
    assert w.take_withdrawal() and w.take() is None and w.current is None
    assert not w.take_withdrawal()  # once


def test_a_file_is_taken_only_when_stable_across_two_polls(tmp_path):
    w = _watcher(tmp_path)
    assert w.poll() is None
    write_model(tmp_path, "m.onnx", tiny_model_bytes())
    assert w.poll() is None  # first sighting
    model = w.poll()
    assert model is not None and w.take() is model and w.take() is None
    assert w.poll() is None  # not loaded again


def test_a_growing_file_is_not_picked_up(tmp_path):
    data = tiny_model_bytes()
    w = _watcher(tmp_path)
    path = tmp_path / "copying.onnx"
    path.write_bytes(data[: len(data) // 2])
    os.chmod(path, 0o644)
    assert w.poll() is None
    with path.open("ab") as f:  # the copy goes on between polls
        f.write(data[len(data) // 2 :])
    assert w.poll() is None
    assert w.rejections == []  # never tried while it changed
    assert w.poll() is not None


def test_temporary_names_are_ignored(tmp_path):
    w = _watcher(tmp_path)
    for name in (".m.onnx.tmp", "m.onnx.part", ".hidden.onnx"):
        (tmp_path / name).write_bytes(tiny_model_bytes())
        os.chmod(tmp_path / name, 0o644)
    for _ in range(3):
        assert w.poll() is None
    assert w.rejections == []


@pytest.mark.parametrize("mode", [0o666, 0o664, 0o646])
def test_group_or_world_writable_is_refused(tmp_path, mode):
    write_model(tmp_path, "open.onnx", tiny_model_bytes(), mode=mode)
    w = _watcher(tmp_path)
    assert w.poll(require_stable=False) is None
    assert "writable by group or others" in w.rejections[0].reason


def test_symlink_and_foreign_owner_are_refused(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    target = write_model(elsewhere, "m.onnx", tiny_model_bytes())
    models = tmp_path / "models"
    models.mkdir()
    (models / "link.onnx").symlink_to(target)
    w = _watcher(models)
    assert w.poll(require_stable=False) is None
    assert "not a regular file" in w.rejections[0].reason
    # owned by the service user? pretend the service runs as another uid than the file's owner
    w2 = ModelWatcher(elsewhere, loader=load_model, service_uid=os.geteuid() + 12345)
    if os.geteuid() != 0:
        assert w2.poll(require_stable=False) is None
        assert "owned by uid" in w2.rejections[0].reason


def test_broken_model_is_rejected_and_the_old_keeps_serving(tmp_path):
    write_model(tmp_path, "good.onnx", tiny_model_bytes(), mtime=time.time() - 100)
    w = _watcher(tmp_path)
    good = w.poll(require_stable=False)
    assert good is not None
    data = tiny_model_bytes(tag="next")
    write_model(tmp_path, "truncated.onnx", data[: len(data) - 40], mtime=time.time() - 20)  # settled
    w.poll()
    assert w.poll() is None
    assert w.rejections and w.rejections[0].path.name == "truncated.onnx"
    assert "truncated.onnx" in w.rejections[0].reason


def test_scene_mismatch_is_rejected_with_its_reason(tmp_path):
    write_model(tmp_path, "all-pads.onnx", tiny_model_bytes(pads=(0, 1, 2, 3, 4, 5),
                                                            pad_sizes=(84, 78, 84, 78, 84, 78)))
    write_model(tmp_path, "three-classes.onnx", tiny_model_bytes(classes=("pull", "push", "hold")))
    w = _watcher(tmp_path, scene={"pads": "distal"})
    assert w.poll(require_stable=False) is None
    reasons = {r.path.name: r.reason for r in w.rejections}
    assert "pads" in reasons["all-pads.onnx"]
    assert "bump" in reasons["three-classes.onnx"]
    w2 = _watcher(tmp_path, scene={"pads": "all"})
    model = w2.poll(require_stable=False)
    assert model is not None and model.path.name == "all-pads.onnx"


def test_continuous_mode_needs_a_dormant_class(tmp_path):
    write_model(tmp_path, "m.onnx", tiny_model_bytes())
    w = _watcher(tmp_path, scene={"mode": "continuous"})
    assert w.poll(require_stable=False) is None
    assert "dormant" in w.rejections[0].reason


def test_background_thread_offers_a_dropped_model(tmp_path):
    w = _watcher(tmp_path)
    w.start()
    try:
        write_model(tmp_path, "m.onnx", tiny_model_bytes())
        deadline = time.monotonic() + 5
        while w.pending is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert w.take() is not None
    finally:
        w.stop()


def test_a_deleted_model_folder_says_what_to_do(tmp_path, caplog):
    import logging

    folder = tmp_path / "models"
    folder.mkdir()
    w = _watcher(folder)
    folder.rmdir()
    with caplog.at_level(logging.ERROR, logger="handover"):
        assert w.poll() is None
        assert w.poll() is None  # said once, not on every poll
    lines = [r.getMessage() for r in caplog.records]
    assert lines == [f"model folder {folder} does not exist (deleted or renamed?): create it (mkdir -p, readable "
                     "by the service user) or fix model.folder and reload; models dropped there are then picked up"]


def test_a_file_name_with_control_characters_is_one_line_once_and_never_read(tmp_path, caplog):
    """A model file named 'z\\n<time> ERROR ...' put a forged line in the journal with every line about it."""
    import logging

    now = time.time()
    forged = "z\n2026-01-01T00:00:00.000Z ERROR handover.daemon: forged.onnx"
    write_model(tmp_path, forged, tiny_model_bytes(tag="forged"), mtime=now - 50)
    write_model(tmp_path, "red\x1b[31m.onnx", tiny_model_bytes(tag="red"), mtime=now - 40)
    w = _watcher(tmp_path)
    with caplog.at_level(logging.INFO, logger="handover.models"):
        assert w.poll(require_stable=False) is None
        assert w.poll() is None and w.poll() is None
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and all("\n" not in x and "\x1b" not in x for x in lines)
    assert all("has control characters in its name and is not read; rename it" in x for x in lines)
    assert w.unreadable_names == {forged, "red\x1b[31m.onnx"} and not w.rejections


def test_a_rejected_file_is_logged_once_per_version_across_reloads(tmp_path, caplog):
    """A daemon reloaded for months (scene, model settings) weighs a broken file again each time: its
    line is logged and counted once per version and reason; the health view still shows it."""
    import logging

    from runtime.config import load_config
    from runtime.daemon import Daemon

    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "good.onnx", tiny_model_bytes(), mtime=time.time() - 200)
    broken = write_model(models, "broken.onnx", b"not a model", mtime=time.time() - 100)
    config = tmp_path / "h.toml"
    base = f'[device]\nurl = "sim://"\n[sinks]\nstdout = false\n[model]\nfolder = "{models}"\n'
    config.write_text(base)
    daemon = Daemon(load_config(config))

    def weigh_again(text: str) -> None:
        config.write_text(text)
        daemon.reload()
        daemon.models.watcher.stop()  # polled here, not by its thread
        daemon.models.watcher.poll(require_stable=False)

    def said() -> list[str]:
        return [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR and "broken.onnx" in r.getMessage()]

    try:
        with caplog.at_level(logging.INFO, logger="handover"):
            daemon.models.start()
            daemon.models.watcher.stop()
            for text in (base + '[scene]\nevents = ["pull", "push"]\n', base, base + "poll_interval_s = 0.5\n", base):
                weigh_again(text)
            assert len(said()) == 1, said()
            assert daemon.health.models_rejected == 1
            assert "broken.onnx rejected" in daemon.health.snapshot()["recent_errors"][-1]["error"]
            write_model(models, "broken.onnx", b"still not a model", mtime=time.time() - 50)  # a new version
            weigh_again(base + '[scene]\nevents = ["pull"]\n')
            assert len(said()) == 2 and daemon.health.models_rejected == 2, said()
    finally:
        daemon.models.stop()
        daemon.sinks.close()
    assert broken.exists() and daemon.health.model_id is not None


def test_a_model_over_the_time_budget_is_logged_once_though_each_weighing_measures_anew(tmp_path, caplog):
    """The too-slow line carries the measured median, which differs on every weighing: a reload that
    weighs the same file again must not log and count it again for that figure alone."""
    import logging
    import shutil

    shutil.copy(Path(__file__).resolve().parents[1] / "examples" / "report-simulated" / "model.onnx", tmp_path / "m.onnx")
    os.utime(tmp_path / "m.onnx", (time.time() - 100, time.time() - 100))
    rejected = []
    w = ModelWatcher(tmp_path, loader=lambda p: load_model(p, warm_up=False), decision_budget=1e-9,
                     on_reject=rejected.append)  # any real decision takes longer than 31 ps
    with caplog.at_level(logging.DEBUG, logger="handover"):
        for _ in range(8):
            w.rescan(keep_current=True)  # what a reload of [scene] or [model] does
            assert w.poll(require_stable=False) is None
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]  # the medians of 8 weighings vary
    assert len(errors) == 1 and "over the budget" in errors[0].getMessage(), [e.getMessage() for e in errors]
    assert [r.repeat for r in rejected] == [False] + [True] * 7
