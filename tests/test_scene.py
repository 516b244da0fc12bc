"""Does a model fit the scene: the shipped config follows the model's pads, a pinned scene refuses
other pads, and every refusal says what to do next (runtime/scene.py)."""

from __future__ import annotations

import functools
import threading
from pathlib import Path

import pytest

from firmware_io.layout import SensorLayout
from runtime.config import load_config
from runtime.model import load_model
from runtime.scene import scene_pads, scene_problem
from tests.tiny_models import tiny_model_bytes, write_model
from tests.waiting import wait_for

pytest.importorskip("onnx")
ROOT = Path(__file__).resolve().parents[1]
SDH2 = SensorLayout.sdh2()
ALL = {"pads": (0, 1, 2, 3, 4, 5), "pad_sizes": (84, 78, 84, 78, 84, 78)}


def _shipped_config(folder: Path, **lines: str) -> Path:
    """deploy/handover.toml changed only in device URL and folders, and in the given lines
    (``scene__pads='"distal"'`` sets ``pads`` of ``[scene]``)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "models").mkdir(exist_ok=True)
    text = (ROOT / "deploy" / "handover.toml").read_text()
    text = text.replace('url = "serial:///dev/dsacon32m"', 'url = "sim://?events=4&realtime=0&loop=0"')
    text = text.replace("/var/lib/handover/models", str(folder / "models"))
    text = text.replace("/var/lib/handover/status.json", str(folder / "status.json"))
    lines = {k.replace("__", "."): v for k, v in lines.items()}
    out, section = [], ""
    for line in text.splitlines():
        if line.startswith("["):
            section = line.strip("[] ")
        key = f"{section}.{line.split('=')[0].strip().lstrip('# ')}"
        out.append(f"{key.split('.')[-1]} = {lines[key]}" if key in lines and "=" in line else line)
    path = folder / "handover.toml"
    path.write_text("\n".join(out) + "\n")
    return path


def _model(tmp_path: Path, name: str, **kw):
    return load_model(write_model(tmp_path, name, tiny_model_bytes(**kw)), warm_up=False)


def test_shipped_config_follows_the_models_pads(tmp_path):
    cfg = load_config(_shipped_config(tmp_path))
    assert cfg.scene.pads == "model"
    for name, kw in (("all.onnx", ALL), ("distal.onnx", {})):
        model = _model(tmp_path, name, **kw)
        assert scene_problem(model, cfg, SDH2) is None
        assert scene_pads(cfg.scene, model, SDH2) == tuple(model.meta.pads)
    assert scene_pads(cfg.scene, None, SDH2) == (0, 1, 2, 3, 4, 5)  # before a model serves


def test_pinned_scene_refuses_other_pads_and_says_what_to_do(tmp_path):
    path = _shipped_config(tmp_path, scene__pads='"distal"')
    cfg = load_config(path)
    problem = scene_problem(_model(tmp_path, "all.onnx", **ALL), cfg, SDH2)
    assert "model expects pads [0, 1, 2, 3, 4, 5], the scene uses [1, 3, 5]" in problem
    assert f'set scene.pads = "model" (follow the model) in {path}' in problem
    assert "systemctl reload handover" in problem and problem.endswith("or train with --pads distal")


@pytest.mark.parametrize("pinned, suggests", [('"all"', "--pads all"), ('"0,1,2,3,4,5"', "--pads all"),
                                              ('"1,3"', "--pads 1,3")])
def test_the_pads_suggested_are_named_when_a_name_selects_them(tmp_path, pinned, suggests):
    """`train with --pads 0,1,2,3,4,5` for all pads: the name train takes is shorter and clearer."""
    cfg = load_config(_shipped_config(tmp_path, scene__pads=pinned))
    problem = scene_problem(_model(tmp_path, "d.onnx"), cfg, SDH2)
    assert problem.endswith(f"or train with {suggests}"), problem


def test_every_refusal_names_a_fix(tmp_path):
    cfg = load_config(_shipped_config(tmp_path))
    cont = load_config(_shipped_config(tmp_path / "continuous", scene__mode='"continuous"'))
    cases = [
        (cfg, {"pads": (1, 3, 7), "pad_sizes": (78, 78, 78)}, "train a model on recordings of this hand"),
        (cfg, {"pad_sizes": (78, 78, 70)}, "train on recordings of this hand"),
        (cfg, {"classes": ("pull", "push", "hold")}, "list only these classes in scene.events"),
        (cont, {}, 'set scene.mode = "trigger"'),
    ]
    for i, (c, kw, fix) in enumerate(cases):
        problem = scene_problem(_model(tmp_path, f"m{i}.onnx", **kw), c, SDH2)
        assert problem and fix in problem, (kw, problem)


def test_daemon_with_the_shipped_config_serves_an_all_pads_model(tmp_path):
    """The path of issue 15: a model trained on all six pads, the shipped config, events out."""
    from runtime.daemon import Daemon
    from runtime.sdnotify import Notifier

    # the simulated hand presses lightly (synthetic): a low trigger level makes every event trigger
    cfg = load_config(_shipped_config(tmp_path, sinks__stdout="false", trigger__fraction="0.02",
                                      trigger__hysteresis="0.01"))
    write_model(tmp_path / "models", "all.onnx", tiny_model_bytes(**ALL))
    events = []
    daemon = Daemon(cfg, notifier=Notifier({}), on_event=events.append)
    stopper = threading.Thread(target=lambda: (_wait(lambda: daemon.health.device_faults >= 1), daemon.request_stop()))
    stopper.start()
    daemon.run()
    stopper.join()
    assert daemon.health.models_rejected == 0
    assert len(events) >= 3 and all(e.model_id == events[0].model_id for e in events)


_wait = functools.partial(wait_for, timeout=30.0)
