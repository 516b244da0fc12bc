"""The daemon's TOML configuration: section classes built from the declared keys, and one clear
message per error.

The keys are declared once, in ``runtime.config_keys``; this module builds the frozen section classes,
reads every key by its type and adds the checks a type and range cannot say. Unknown keys are errors
(a typo would otherwise be ignored); a problem raises :class:`ConfigError` naming the key.
"""

from __future__ import annotations

import os
import re
import stat
import tomllib
from collections.abc import Callable
from dataclasses import field, make_dataclass, replace
from pathlib import Path
from typing import Any

from firmware_io.layout import LayoutError, SensorLayout
from firmware_io.transports import TransportError, validate_url
from firmware_io.trigger_level import is_trigger_level
from runtime.config_keys import RANGES, SECTIONS, Key, key, section_keys
from runtime.config_read import ConfigError, no_control_chars, no_unknown, read_key, read_str, read_str_list
from runtime.instance_name import instance_problem

__all__ = [
    "FOLLOW_MODEL", "NO_SINK_LEFT", "RANGES", "Config", "ConfigError", "ContinuousConfig", "ControlConfig",
    "DeviceConfig", "ModelConfig", "Ros2Config", "SceneConfig", "SinksConfig", "TriggerConfig", "config_from_dict",
    "load_config", "parse_host_port"
]

MODES = key("scene.mode").choices
KNOWN_EVENTS = ("pull", "push", "hold", "bump", "dormant")
"""The paper's four actions and the trainer's dormant class; a custom model may have others."""
FOLLOW_MODEL = "model"
"""``scene.pads`` value meaning: the pads the serving model was trained on."""
NO_SINK_LEFT = ("events go nowhere: no other sink is configured (set sinks.stdout = true, or add sinks.udp or "
                "sinks.unix targets)")
"""What to say when the only event sink is ROS 2 and it cannot start."""


def _annotation(k: Key) -> str:
    name = "tuple[str, ...]" if k.type is tuple else k.type.__name__
    return f"{name} | None" if k.optional else name


def _section_class(name: str, section: str, doc: str, **methods: Any) -> type:
    """A frozen dataclass with one field per config key of ``section``, its default the key's."""
    specs = [(k.short, _annotation(k), field(default=k.config_default)) for k in section_keys(section)]
    return make_dataclass(name, specs, frozen=True, namespace={"__doc__": doc, "__module__": __name__, **methods})


def _n_without_ros2(self: Any) -> int:
    """How many sinks events reach when ROS 2 cannot start."""
    return int(self.stdout) + len(self.udp) + len(self.unix)


DeviceConfig = _section_class("DeviceConfig", "device", "``[device]``: the link to the hand.")
SceneConfig = _section_class("SceneConfig", "scene", "``[scene]``: the pads in contact, the reported classes, the mode.")
ModelConfig = _section_class("ModelConfig", "model", "``[model]``: the folder of models and what a model may cost.")
TriggerConfig = _section_class(
    "TriggerConfig", "trigger", "``[trigger]``: unset (None) keys take the model's recorded trigger settings, else "
    "the default (runtime/trigger_settings.py, ``resolve_trigger``).")
ContinuousConfig = _section_class("ContinuousConfig", "continuous",
                                  "``[continuous]``: the report rule of continuous mode (runtime/decision.py).")
SinksConfig = _section_class("SinksConfig", "sinks", "``[sinks]``: where events go.",
                             n_without_ros2=property(_n_without_ros2))
OnnxConfig = _section_class("OnnxConfig", "onnxruntime", "``[onnxruntime]``: the session's threads.")
Ros2Config = _section_class("Ros2Config", "ros2", "``[ros2]``: the ROS 2 sink (runtime/ros2_node.py).")
ControlConfig = _section_class("ControlConfig", "control", "``[control]``: the robot's grasp and arm messages.")
CaptureConfig = _section_class("CaptureConfig", "capture", "``[capture]``: field capture (runtime/capture.py).")

_SECTION_CLASSES: dict[str, type] = {
    "device": DeviceConfig, "scene": SceneConfig, "model": ModelConfig, "trigger": TriggerConfig,
    "continuous": ContinuousConfig, "sinks": SinksConfig, "onnxruntime": OnnxConfig, "ros2": Ros2Config,
    "control": ControlConfig, "capture": CaptureConfig,
}
assert set(_SECTION_CLASSES) == set(SECTIONS) - {""}, "every declared section has its class"

Config = make_dataclass(
    "Config",
    [*((name, cls.__name__, field(default_factory=cls)) for name, cls in _SECTION_CLASSES.items()),
     *((k.short, _annotation(k), field(default=k.config_default)) for k in section_keys("")),
     ("source", "str", field(default="")),
     ("warnings", "tuple[str, ...]", field(default=()))],
    frozen=True,
    namespace={"__module__": __name__, "__doc__": "The whole configuration: one field per section, the top-level "
               "keys, ``source`` (where it was read from, for messages) and ``warnings`` (things allowed but "
               "probably wrong, such as an event name no known model has)."},
)


# -- parsing --------------------------------------------------------------------------------


def load_config(path: str | Path) -> Config:
    """Read and validate a TOML file; raises ConfigError naming the file or the key."""
    p = Path(path)
    try:
        text = read_whole(p).decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: config file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read config file ({exc})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML ({exc})") from None
    if not data:
        raise ConfigError(f"{p}: the config file is empty (half-written by an editor or a deploy tool?); write at "
                          "least one key (deploy/handover.toml is a complete example)")
    return replace(config_from_dict(data), source=str(p))


MAX_CONFIG_BYTES = 1 << 20


def read_whole(path: Path) -> bytes:
    """The bytes of a regular file, read whole and unchanged while reading; OSError (naming what is
    wrong) otherwise. Why: a SIGHUP must never apply half a file (a deploy tool still writing it)
    nor wait on a FIFO that nobody writes; it keeps the running config instead."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        before = os.fstat(fd)
        if not stat.S_ISREG(before.st_mode):
            raise OSError(f"not a regular file (a {_kind(before.st_mode)}); point --config at the file itself")
        if before.st_size > MAX_CONFIG_BYTES:
            raise OSError(f"{before.st_size} bytes, more than a config can be ({MAX_CONFIG_BYTES})")
        chunks = []
        while chunk := os.read(fd, 65536):
            chunks.append(chunk)
        after = os.fstat(fd)
    finally:
        os.close(fd)
    data = b"".join(chunks)
    if (after.st_size, after.st_mtime_ns) != (before.st_size, before.st_mtime_ns) or len(data) != after.st_size:
        raise OSError("it changed while being read (still being written?); send SIGHUP again once it is complete")
    return data


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "FIFO"), (stat.S_ISDIR, "folder"), (stat.S_ISCHR, "character device"),
                       (stat.S_ISBLK, "block device"), (stat.S_ISSOCK, "socket")):
        if test(mode):
            return name
    return "special file"


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build a Config from parsed TOML; raises ConfigError naming the first bad key.

    Sections are read in the declared order, each key in its declared order, so the first bad key
    is the one reported."""
    if not isinstance(data, dict):
        raise ConfigError("config: must be a table")
    no_unknown("", data, set(_SECTION_CLASSES) | {k.short for k in section_keys("")})
    no_control_chars(data)
    for name in _SECTION_CLASSES:
        if name in data and not isinstance(data[name], dict):
            raise ConfigError(f"{name}: must be a table ([{name}])")
    sections = {name: _read_section(name, data.get(name, {})) for name in _SECTION_CLASSES}
    top = _read_values("", data)
    warnings = [
        f"scene.events: {e!r} is not a known event ({', '.join(KNOWN_EVENTS)}); "
        "it is reported only if the model has such a class"
        for e in sections["scene"].events if e not in KNOWN_EVENTS
    ]
    if sections["scene"].mode == "continuous" and sections["scene"].early_events is not None:
        warnings.append("scene.early_events: has no effect in continuous mode (every frame is classified, "
                        "no window waits for its full length); remove it or set scene.mode = \"trigger\"")
    _capture_apart(sections["capture"].folder, sections["model"])
    return Config(**sections, **top, warnings=tuple(warnings))


def _capture_apart(capture: str | None, model: Any) -> None:
    """A capture folder that is a model folder mixes a GB of recordings with the models a deploy replaces."""
    for name, folder in (("model.folder", model.folder), ("model.shadow", model.shadow)):
        if capture and folder and os.path.realpath(capture) == os.path.realpath(Path(folder).expanduser()):
            raise ConfigError(f"capture.folder: {capture} is {name}: recordings would mix with the models; name a "
                              "folder of its own (e.g. /var/lib/handover/field)")


def _read_values(section: str, table: dict) -> dict[str, Any]:
    keys = section_keys(section)
    if section:
        no_unknown(section, table, {k.short for k in keys})
    values = {k.short: _READERS.get(k.name, read_key)(k, table) for k in keys}
    for check in _SECTION_CHECKS.get(section, ()):
        check(values)
    return values


def _read_section(section: str, table: dict) -> Any:
    return _SECTION_CLASSES[section](**_read_values(section, table))


# -- the checks a type and a range cannot say ---------------------------------------------------


def _device_url(k: Key, table: dict) -> str:
    """The transports' own parser and scheme table: a URL that could never open is a config
    error here, not an endless "retrying" in the daemon. Nothing is opened."""
    url = read_key(k, table)
    try:
        validate_url(url)
    except TransportError as exc:
        raise ConfigError(f"device.url: {exc}") from None
    return url


def _reconnect_order(v: dict) -> None:
    if v["reconnect_max_s"] < v["reconnect_min_s"]:
        raise ConfigError("device.reconnect_max_s: must be >= device.reconnect_min_s")


def _scene_pads(k: Key, table: dict) -> str:
    """``model``, or a selection some layout could satisfy (the real check runs when the device reports
    its layout); a list of pad indices reads as ``1,3,5``."""
    pads = table.get("pads", k.default)
    if isinstance(pads, list) and pads and all(isinstance(p, int) and not isinstance(p, bool) for p in pads):
        pads = ",".join(str(p) for p in pads)
    if not isinstance(pads, str) or not pads.strip():
        raise ConfigError(f"scene.pads: must be 'model' or a pad selection like 'distal' or [1, 3, 5], got {pads!r}")
    if pads.strip().lower() == FOLLOW_MODEL:
        return FOLLOW_MODEL
    try:
        SensorLayout.sdh2().pads(pads)
    except LayoutError as exc:
        if "no matrix" not in str(exc):  # indices are checked against the device's own layout later
            raise ConfigError(f"scene.pads: {exc}") from None
    return pads.strip()


def _scene_events(k: Key, table: dict) -> tuple[str, ...]:
    events = read_str_list(k.name, table, k.default)
    if not events:
        raise ConfigError("scene.events: must name at least one event")
    return events


def _trigger_fraction(k: Key, table: dict) -> float | None:
    fraction = read_key(k, table)
    if fraction is not None and not is_trigger_level(fraction):
        raise ConfigError(f"trigger.fraction: must be a number in (0, 1), got {fraction}")
    return fraction


def _hysteresis_below_fraction(v: dict) -> None:
    if v["fraction"] is not None and v["hysteresis"] is not None and v["hysteresis"] >= v["fraction"]:
        raise ConfigError(f"trigger.hysteresis: must be smaller than trigger.fraction ({v['fraction']})")


def _sinks_udp(k: Key, table: dict) -> tuple[str, ...]:
    udp = read_key(k, table)
    for target in udp:
        parse_host_port(target, key=k.name)
    return udp


def _sinks_unix(k: Key, table: dict) -> tuple[str, ...]:
    unix = read_key(k, table)
    for path in unix:
        if not path.startswith("/") and not path.startswith("@"):
            raise ConfigError(f"sinks.unix: socket path must be absolute, got {path!r}")
    return unix


def _control_socket(k: Key, table: dict) -> str | None:
    sock = table.get(k.short)
    if sock is not None and (not isinstance(sock, str) or not (sock.startswith("/") or sock.startswith("@"))):
        raise ConfigError(f"control.socket: must be an absolute path or @abstract name, got {sock!r}")
    return sock


def _capture_folder(k: Key, table: dict) -> str | None:
    folder = table.get(k.short)
    if folder is not None and (not isinstance(folder, str) or not folder.startswith("/")):
        raise ConfigError(f"capture.folder: must be an absolute path, e.g. /var/lib/handover/field, got {folder!r}")
    return folder


def _log_level(k: Key, table: dict) -> str:
    log_level = read_str(k.name, table, k.default).lower()
    if log_level not in k.choices:
        raise ConfigError(f"log_level: must be one of {', '.join(k.choices)}, got {log_level!r}")
    return log_level


def _state_file(k: Key, table: dict) -> str | None:
    """``health_file``, ``model.quarantine_file``: a path naming a file (not a folder) whose folder
    exists, or None. Why: a folder there (``/``, ``.``) passed once and then crashed the daemon at
    its first write, or left a model that broke the contract in service."""
    value = table.get(k.short)
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{k.name}: must be a path, got {value!r}")
    path = Path(value).expanduser()
    if path.name in ("", ".", "..") or path.is_dir():
        raise ConfigError(f"{k.name}: {value} is a folder, not a file; name a file in it (e.g. "
                          f"{path.resolve() / ('status.json' if k.name == 'health_file' else 'quarantined-models.json')})")
    if not path.parent.is_dir():
        raise ConfigError(f"{k.name}: folder {path.parent} does not exist (create it, or drop {k.name})")
    return value


def _instance(k: Key, table: dict) -> str | None:

    name = table.get(k.short)
    if name is not None and (problem := instance_problem(name)):
        raise ConfigError(f"instance: {problem}")
    return name


_ROS_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _ros2_namespace(k: Key, table: dict) -> str:
    namespace = read_key(k, table)
    tokens = namespace.split("/")
    if not namespace.startswith("/") or not all(_ROS_TOKEN.fullmatch(t) for t in tokens[1:]):
        raise ConfigError(f"ros2.namespace: must look like /handover or /robot/hand (letters, digits, _), got {namespace!r}")
    return namespace


def _ros2_node_name(k: Key, table: dict) -> str:
    node_name = read_key(k, table)
    if not _ROS_TOKEN.fullmatch(node_name):
        raise ConfigError(f"ros2.node_name: letters, digits and _ (not starting with a digit), got {node_name!r}")
    return node_name


ROS_TOPIC_MAX = 255 - 8
"""The longest topic name rclpy takes (its limit, ``255U - 8U``): a longer one fails the node's start."""


def _ros2_joint_states(k: Key, table: dict) -> str | None:
    topic = read_key(k, table)
    if topic is None:
        return None
    tokens = topic.removeprefix("/").split("/")  # one leading '/': rclpy refuses '//joint_states'
    if not all(_ROS_TOKEN.fullmatch(t) for t in tokens):
        raise ConfigError(f"ros2.joint_states: must be a topic name like /joint_states or /arm/joint_states "
                          f"(letters, digits, _), got {topic!r}")
    namespace = table.get("namespace") if isinstance(table.get("namespace"), str) else key("ros2.namespace").default
    full = topic if topic.startswith("/") else f"{namespace}/{topic}"  # a relative name is under the namespace
    if len(full) > ROS_TOPIC_MAX:
        raise ConfigError(f"ros2.joint_states: {full[:40]}... is {len(full)} characters, ROS 2 takes at most "
                          f"{ROS_TOPIC_MAX}; name a shorter topic")
    return topic


_READERS: dict[str, Callable[[Key, dict], Any]] = {
    "device.url": _device_url, "scene.pads": _scene_pads, "scene.events": _scene_events,
    "trigger.fraction": _trigger_fraction, "sinks.udp": _sinks_udp, "sinks.unix": _sinks_unix,
    "control.socket": _control_socket, "capture.folder": _capture_folder, "log_level": _log_level, "health_file": _state_file,
    "model.quarantine_file": _state_file,
    "instance": _instance,
    "ros2.namespace": _ros2_namespace, "ros2.node_name": _ros2_node_name, "ros2.joint_states": _ros2_joint_states,
}
"""Keys read with more than their declared type and range."""


def _early_within_events(v: dict) -> None:
    if v["early_events"] is not None and (stray := [e for e in v["early_events"] if e not in v["events"]]):
        raise ConfigError(f"scene.early_events: {', '.join(map(repr, stray))} not in scene.events "
                          f"({', '.join(v['events'])}); list only reported events")


def _shadow_apart(v: dict) -> None:
    """A shadow folder that is the model folder would serve its candidate; one that is a file never holds one."""
    if v["shadow"] is None:
        return
    shadow, folder = Path(v["shadow"]).expanduser(), Path(v["folder"]).expanduser()
    if os.path.realpath(shadow) == os.path.realpath(folder):  # Path.resolve raises on a symlink loop
        raise ConfigError(f"model.shadow: {v['shadow']} is model.folder: a candidate dropped there would serve, not "
                          "run in shadow; name another folder (e.g. /var/lib/handover/shadow)")
    if shadow.exists() and not shadow.is_dir():
        raise ConfigError(f"model.shadow: {v['shadow']} is not a folder; name the folder candidates are dropped in")


_SECTION_CHECKS: dict[str, tuple[Callable[[dict], None], ...]] = {
    "device": (_reconnect_order,), "trigger": (_hysteresis_below_fraction,), "scene": (_early_within_events,),
    "model": (_shadow_apart,),
}
"""Checks of one key against another, after the section's keys were read."""


def parse_host_port(target: str, key: str = "sinks.udp") -> tuple[str, int]:
    """``host:port`` (``[v6]:port`` too) -> (host, port); ConfigError naming the key otherwise."""
    host, sep, port = target.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"{key}: expected host:port, got {target!r}")
    return host, int(port)
