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
    assert cfg.scene.pads == "model" and cfg.scene.mode == "trigger"  # the pads follow the model
    assert cfg.scene.events == ("pull", "push", "hold", "bump")
    assert cfg.trigger.fraction is None  # taken from the model (0.15 in the paper)
    assert cfg.onnxruntime.intra_op_threads == 1 and cfg.onnxruntime.allow_spinning is False
    assert cfg.sinks.stdout is True


DEPLOYED_HEALTH = 'health_file = "/var/lib/handover/status.json"'


def _deployed(tmp_path: Path) -> Config:
    """deploy/handover.toml with its health file moved into tmp_path (systemd's StateDirectory
    creates /var/lib/handover for the service; this machine has none)."""
    text = (ROOT / "deploy" / "handover.toml").read_text()
    assert DEPLOYED_HEALTH in text
    copy = tmp_path / "handover.toml"
    copy.write_text(text.replace(DEPLOYED_HEALTH, f'health_file = "{tmp_path / "status.json"}"'))
    return load_config(copy)


def test_default_deploy_config_is_valid(tmp_path):
    cfg = _deployed(tmp_path)
    assert cfg.device.url.startswith("serial://")
    assert cfg.source.endswith("handover.toml")
    assert cfg.warnings == ()


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
        # URLs the transports could never open: a config error, not an endless "retrying"
        ({"device": {"url": "foo://x"}}, "device.url"),
        ({"device": {"url": "tcp://127.0.0.1:"}}, "device.url"),
        ({"device": {"url": "tcp://127.0.0.1:70000"}}, "device.url"),
        ({"device": {"url": "tcp://:13000"}}, "device.url"),
        ({"device": {"url": "tcp://host:1?timeout=3"}}, "device.url"),
        ({"device": {"url": "sim://?seed=abc"}}, "device.url"),
        ({"device": {"url": "sim://?events=0"}}, "device.url"),
        ({"device": {"url": "sim://?fault=melt"}}, "device.url"),
        ({"device": {"url": "serial://"}}, "device.url"),
        ({"device": {"url": "serial:///dev/ttyUSB0?baud=fast"}}, "device.url"),
        ({"device": {"url": "usb://0403"}}, "device.url"),
        ({"device": {"url": "usb://0403:6001?chip=ch340"}}, "device.url"),
        ({"device": {"url": "hid://zz:ea80"}}, "device.url"),
        ({"device": {"url": "replay://"}}, "device.url"),
        ({"health_file": "/nonexistent-handover-folder/status.json"}, "health_file"),
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


@pytest.mark.parametrize(("data", "key", "char"), [
    ({"model": {"folder": "/tmp/mo\ndels"}}, "model.folder", "\n"),
    ({"control": {"socket": "/run/x\x1b[31m.sock"}}, "control.socket", "\x1b"),
    ({"sinks": {"unix": ["/run/a.sock", "/run/b\r.sock"]}}, "sinks.unix", "\r"),
    ({"health_file": "/tmp/s\x00.json"}, "health_file", "\x00"),
])
def test_a_control_character_in_any_string_is_one_line_naming_the_key(data, key, char):
    """A newline in model.folder printed 'model.folder /tmp/mo' and 'dels does not exist' as two lines;
    only NUL was refused."""
    with pytest.raises(ConfigError) as info:
        config_from_dict(data)
    message = str(info.value)
    assert message.startswith(f"{key}: must not contain a control character ({char!r})"), message
    assert message.isprintable()


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
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('sklearn', 'matplotlib', 'onnx'));"
        "print('HEAVY', bad); sys.exit(rc)"
    )
    proc = subprocess.run([sys.executable, "-c", code, str(cfg)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert "HEAVY []" in proc.stdout, proc.stdout + proc.stderr
    assert "would serve model" in proc.stdout and proc.returncode == 0


def test_continuous_rule_keys():
    cfg = config_from_dict({"continuous": {"confirm_frames": 4, "min_margin": 0.5, "rearm_frames": 0}})
    assert (cfg.continuous.confirm_frames, cfg.continuous.min_margin, cfg.continuous.rearm_frames) == (4, 0.5, 0)

def test_deploy_config_shows_the_defaults(tmp_path):
    deployed, defaults = _deployed(tmp_path), config_from_dict({})
    assert deployed.continuous == defaults.continuous, "deploy/handover.toml shows the defaults"
    assert deployed.trigger == defaults.trigger, "deploy/handover.toml shows the defaults"
    assert deployed.ros2 == defaults.ros2 and deployed.sinks == defaults.sinks, "deploy/handover.toml shows the defaults"


@pytest.mark.parametrize("url", ["serial:///dev/ttyUSB0", "/dev/dsacon32m", "tcp://192.168.1.42:13000",
                                 "tcp://[::1]:13000?connect_timeout=0.5", "tcp://robot", "sim://?seed=3&events=5&realtime=0",
                                 "replay:///data/x.hrec?speed=max&loop=1", "usb://0403:6001?chip=ftdi&interface=0",
                                 "hid://10c4:ea80?baud=115200", "subject://?seed=2&speed=max&drop=3,9&seconds=2"])
def test_good_urls_pass_without_opening_anything(url):
    scheme = url.partition(":")[0]
    if scheme in ("usb", "hid"):
        pytest.importorskip(scheme)  # validate_url names the missing package otherwise
    assert config_from_dict({"device": {"url": url}}).device.url == url


@pytest.mark.parametrize("url", ["foo://x", "tcp://127.0.0.1:", "tcp://h:1?x=1", "sim://?seed=abc", "sim://?fault=melt",
                                 "serial://", "usb://0403:6001?chip=ch340", "hid://10c4", "replay://",
                                 "sim://?realtime=0&speed=fast", "subject://?sped=2", "subject://?drop=x",
                                 "subject://?speed=-1"])
def test_validate_url_agrees_with_open_transport(url):
    """Whatever validate_url refuses, open_transport refuses too, with a TransportError that is
    not DeviceUnavailable (so the check and the real thing cannot drift apart unnoticed)."""
    from firmware_io.transports import DeviceUnavailable, TransportError, open_transport, validate_url

    with pytest.raises(TransportError) as checked:
        validate_url(url)
    with pytest.raises(TransportError) as opened:
        open_transport(url)
    for info in (checked, opened):
        assert not isinstance(info.value, DeviceUnavailable), info.value
    assert str(checked.value).startswith(url + ":") or "scheme" in str(checked.value)


def test_unknown_event_names_are_a_warning_not_an_error():
    cfg = config_from_dict({"scene": {"events": ["pull", "pul"]}})
    assert len(cfg.warnings) == 1 and "'pul'" in cfg.warnings[0] and cfg.warnings[0].startswith("scene.events:")
    assert config_from_dict({"scene": {"events": ["pull", "dormant"]}}).warnings == ()


def _config_file(tmp_path: Path, models: Path, extra: str = "") -> Path:
    cfg = tmp_path / "h.toml"
    cfg.write_text(f'[device]\nurl = "sim://"\n[model]\nfolder = "{models}"\n{extra}')
    return cfg


def test_check_passes_with_an_empty_model_folder_unless_a_model_is_required(tmp_path):
    """The service's ExecStartPre runs --check; the daemon is built to wait for a model."""
    empty = tmp_path / "models"
    empty.mkdir()
    cfg = _config_file(tmp_path, empty)
    proc = _run_cli("--config", str(cfg), "--check")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("handover run: warning: no model in"), proc.stderr
    strict = _run_cli("--config", str(cfg), "--check", "--require-model")
    assert strict.returncode == 1
    assert strict.stderr.startswith("handover run: ") and len(strict.stderr.strip().splitlines()) == 1


def test_check_names_an_event_the_model_lacks(tmp_path):
    from tests.tiny_models import tiny_model_bytes, write_model

    models = tmp_path / "models"
    models.mkdir()
    write_model(models, "m.onnx", tiny_model_bytes())
    proc = _run_cli("--config", str(_config_file(tmp_path, models, '[scene]\nevents = ["pull", "pul"]\n')), "--check")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("handover run: scene.events: 'pul' is not a class of model ")
    assert "(classes: pull, push, hold, bump)" in lines[0]


def test_run_with_a_url_that_can_never_open_is_one_line_and_exit_2(tmp_path):
    cfg = tmp_path / "h.toml"
    cfg.write_text('[device]\nurl = "tcp://127.0.0.1:"\n')
    for args in (("--check",), ()):
        proc = _run_cli("--config", str(cfg), *args)
        assert proc.returncode == 2
        assert proc.stderr.strip().splitlines() == [
            "handover run: device.url: tcp://127.0.0.1:: expected tcp://HOST:PORT with a port 1..65535"]


@pytest.mark.parametrize(
    ("section", "key", "value"),
    [
        ("device", "stall_timeout_s", "nan"),
        ("device", "stall_timeout_s", "inf"),
        ("device", "reconnect_max_s", "+inf"),
        ("model", "max_bytes", "99999999999999999999"),
        ("model", "poll_interval_s", "-inf"),
        ("model", "decision_budget", "2.0"),
        ("trigger", "fraction", "nan"),
        ("trigger", "refractory_s", "inf"),
        ("trigger", "baseline_tau_s", "nan"),
        ("continuous", "min_margin", "nan"),
        ("continuous", "rearm_frames", "99999999999999999999"),
    ],
)
def test_every_number_is_finite_and_in_its_stated_range(tmp_path, section, key, value):
    """TOML spells nan and inf; each must be refused with the key, the value and the range."""
    from runtime.config import RANGES

    path = tmp_path / "bad.toml"
    path.write_text(f"[{section}]\n{key} = {value}\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{section}.{key}:"), message
    assert value.lstrip("+")[:8] in message and "\n" not in message
    if section != "trigger" or key != "fraction":
        lo, hi = RANGES[f"{section}.{key}"]
        assert f"[{lo:g}, {hi:g}]" in message or f"[{int(lo)}, {int(hi)}]" in message


def test_every_numeric_default_is_inside_its_range():
    from runtime.config import RANGES

    cfg = config_from_dict({})
    for key, (lo, hi) in RANGES.items():
        section, _, name = key.rpartition(".")
        value = getattr(getattr(cfg, section) if section else cfg, name)
        if value is not None:
            assert lo <= value <= hi, key


@pytest.mark.parametrize("url", ["tcp://[::1", "tcp://]x:1", "serial://[x", "hid://[::", "tcp://[zz]:1"])
def test_a_malformed_url_is_a_config_error(tmp_path, url):
    path = tmp_path / "h.toml"
    path.write_text(f'[device]\nurl = "{url}"\n')
    with pytest.raises(ConfigError, match=r"^device\.url: .*(IPv6|\[|\])") as info:
        load_config(path)
    assert "\n" not in str(info.value)
    done = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--check", "--config", str(path)], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr and "device.url" in done.stderr


@pytest.mark.parametrize("failure", ["malformed url", "unexpected exception"])
def test_sighup_never_kills_the_daemon_it_keeps_the_running_configuration(tmp_path, caplog, monkeypatch, failure):
    import logging

    import runtime.daemon
    from runtime.daemon import Daemon

    path = tmp_path / "h.toml"
    good = f'[device]\nurl = "sim://"\n[sinks]\nstdout = false\n[model]\nfolder = "{tmp_path}"\n'
    path.write_text(good)
    daemon = Daemon(load_config(path))
    if failure == "malformed url":
        path.write_text(good.replace("sim://", "tcp://[::1"))
    else:
        def broken(source):
            raise RuntimeError("a bug in a check\nsecond line")
        monkeypatch.setattr(runtime.daemon, "load_config", broken)
    try:
        with caplog.at_level(logging.ERROR, logger="handover.daemon"):
            daemon.reload()
    finally:
        daemon.sinks.close()
    assert daemon.cfg.device.url == "sim://"
    lines = [r.getMessage() for r in caplog.records if r.name == "handover.daemon"]
    assert len(lines) == 1 and lines[0].startswith("SIGHUP: ") and "\n" not in lines[0]
    assert lines[0].endswith("; keeping the running configuration")
    assert ("tcp://[::1" if failure == "malformed url" else "RuntimeError: a bug in a check") in lines[0]
    assert "reload refused" in (daemon.health.last_error or "")


def test_a_reload_says_which_sections_changed(tmp_path, caplog):
    """After a SIGHUP the operator reads what the new file changed (the stranger added a UDP sink and
    read only "configuration reloaded")."""
    import logging

    from runtime.config import load_config
    from runtime.daemon import Daemon

    config = tmp_path / "handover.toml"
    base = f'[device]\nurl = "sim://"\n[model]\nfolder = "{tmp_path}"\n'
    config.write_text(base + "[sinks]\nstdout = false\n")
    daemon = Daemon(load_config(config))
    try:
        with caplog.at_level(logging.INFO, logger="handover.daemon"):
            daemon.reload()
            before = daemon.models.counters()["trigger"]
            config.write_text(base + '[sinks]\nstdout = false\nudp = ["127.0.0.1:9"]\n[trigger]\nkind = "threshold"\n'
                                    'fraction = 0.2\n')
            daemon.reload()
        lines = [r.getMessage() for r in caplog.records if "configuration reloaded" in r.getMessage()]
        assert lines[0].endswith("(nothing changed)") and lines[1].endswith("(changed: trigger, sinks)"), lines
        after = daemon.models.counters()["trigger"]  # the health view says the trigger that now starts a window
        assert before.startswith("onset (") and after.startswith("threshold (fraction 0.2,"), (before, after)
    finally:
        daemon.sinks.close()


def test_a_long_instance_name_is_refused_in_one_short_line():
    """The error quotes the start of the name and its length, not the whole value (one journal line)."""
    with pytest.raises(ConfigError, match=r"^instance: must be at most 64 printable") as info:
        config_from_dict({"instance": "x" * 5000})
    assert len(str(info.value)) < 200 and "5000 characters" in str(info.value)
