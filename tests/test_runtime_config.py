"""The daemon's config: defaults, and one clear message naming the key for every error."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from runtime.config import Config, ConfigError, config_from_dict, load_config

ROOT = Path(__file__).resolve().parents[1]


def test_defaults_are_the_papers():
    cfg = config_from_dict({})
    assert isinstance(cfg, Config)
    assert cfg.scene.pads == "distal" and cfg.scene.mode == "trigger"
    assert cfg.scene.events == ("pull", "push", "hold", "bump")
    assert cfg.trigger.fraction is None  # taken from the model (0.15 in the paper)
    assert cfg.onnxruntime.intra_op_threads == 1 and cfg.onnxruntime.allow_spinning is False
    assert cfg.sinks.stdout is True


def test_default_deploy_config_is_valid():
    cfg = load_config(ROOT / "deploy" / "handover.toml")
    assert cfg.device.url.startswith("serial://")
    assert cfg.source.endswith("handover.toml")


@pytest.mark.parametrize(
    ("data", "key"),
    [
        ({"trigger": {"fraction": 1.5}}, "trigger.fraction"),
        ({"trigger": {"fraction": "high"}}, "trigger.fraction"),
        ({"trigger": {"fraction": 0.1, "hysteresis": 0.2}}, "trigger.hysteresis"),
        ({"trigger": {"refractory_s": -1}}, "trigger.refractory_s"),
        ({"scene": {"mode": "sometimes"}}, "scene.mode"),
        ({"scene": {"pads": "elbow"}}, "scene.pads"),
        ({"scene": {"events": []}}, "scene.events"),
        ({"sinks": {"udp": ["localhost"]}}, "sinks.udp"),
        ({"sinks": {"udp": ["localhost:99999"]}}, "sinks.udp"),
        ({"sinks": {"unix": ["relative.sock"]}}, "sinks.unix"),
        ({"sinks": {"stdout": "yes"}}, "sinks.stdout"),
        ({"onnxruntime": {"intra_op_threads": 0}}, "onnxruntime.intra_op_threads"),
        ({"device": {"url": "ttyUSB0"}}, "device.url"),
        ({"device": {"colour": "red"}}, "device.colour"),
        ({"model": "here"}, "model"),
        ({"log_level": "loud"}, "log_level"),
        ({"frobnicate": 1}, "frobnicate"),
        ({"continuous": {"confirm_frames": 0}}, "continuous.confirm_frames"),
        ({"continuous": {"confirm_frames": 2.5}}, "continuous.confirm_frames"),
        ({"continuous": {"min_margin": -0.1}}, "continuous.min_margin"),
        ({"continuous": {"min_margin": "wide"}}, "continuous.min_margin"),
        ({"continuous": {"rearm_frames": -1}}, "continuous.rearm_frames"),
        ({"continuous": {"rearm_frames": True}}, "continuous.rearm_frames"),
        ({"continuous": {"confirm": 3}}, "continuous.confirm"),
        ({"continuous": 3}, "continuous"),
    ],
)
def test_each_error_names_its_key(data, key):
    with pytest.raises(ConfigError) as info:
        config_from_dict(data)
    message = str(info.value)
    assert message.startswith(key + ":"), message
    assert "\n" not in message


def test_pad_lists_and_indices(tmp_path):
    cfg = config_from_dict({"scene": {"pads": [1, 3]}})
    assert cfg.scene.pads == "1,3"


def test_file_errors_name_the_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[device\nurl = 1\n")
    with pytest.raises(ConfigError, match=r"bad\.toml: not valid TOML"):
        load_config(bad)


def _run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "runtime.cli", "run", *args], cwd=ROOT, capture_output=True, text=True, timeout=60
    )


def test_cli_config_error_is_one_line_and_exit_2(tmp_path):
    bad = tmp_path / "h.toml"
    bad.write_text('[trigger]\nfraction = 2.0\n')
    proc = _run_cli("--config", str(bad), "--check")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("handover run: ") and "trigger.fraction" in lines[0]
    assert "Traceback" not in proc.stderr


def test_check_never_imports_training_packages(tmp_path):
    from tests.tiny_models import tiny_model_bytes, write_model

    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes())
    cfg = tmp_path / "h.toml"
    cfg.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\n')
    code = (
        "import sys; from runtime.cli import main; rc = main(['run', '--config', sys.argv[1], '--check']);"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('sklearn', 'matplotlib', 'onnx', 'skl2onnx'));"
        "print('HEAVY', bad); sys.exit(rc)"
    )
    proc = subprocess.run([sys.executable, "-c", code, str(cfg)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert "HEAVY []" in proc.stdout, proc.stdout + proc.stderr
    assert "would serve model" in proc.stdout and proc.returncode == 0


def test_continuous_rule_keys():
    cfg = config_from_dict({"continuous": {"confirm_frames": 4, "min_margin": 0.5, "rearm_frames": 0}})
    assert (cfg.continuous.confirm_frames, cfg.continuous.min_margin, cfg.continuous.rearm_frames) == (4, 0.5, 0)
    deployed = load_config(ROOT / "deploy" / "handover.toml").continuous
    assert deployed == config_from_dict({}).continuous, "deploy/handover.toml shows the defaults"
