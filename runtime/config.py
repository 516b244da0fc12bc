"""The daemon's TOML configuration: dataclasses with defaults, and one clear message per error.

Every key is checked (unknown keys too, since a typo would otherwise be silently ignored), and
a problem raises :class:`ConfigError` whose message names the key, e.g.
``trigger.fraction: must be a number in (0, 1), got 1.5``.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from firmware_io.trigger_level import is_trigger_level
from runtime.config_keys import (  # noqa: F401 - RANGES and ConfigError are part of this module's interface
    RANGES,
    ConfigError,
    no_nul,
    no_unknown,
    read_bool,
    read_int,
    read_num,
    read_optional_num,
    read_str,
    read_str_list,
)
from runtime.realtime import DEFAULT_PRIORITY

MODES = ("trigger", "continuous")
TRIGGER_KINDS = ("onset", "threshold")
KNOWN_EVENTS = ("pull", "push", "hold", "bump", "dormant")
"""The paper's four actions and the trainer's dormant class; a custom model may have others."""
LOG_LEVELS = ("debug", "info", "warning", "error")


@dataclass(frozen=True)
class DeviceConfig:
    url: str = "serial:///dev/dsacon32m"
    stall_timeout_s: float = 2.0
    """No frame for this long while streaming counts as a stall: reconnect."""
    reconnect_min_s: float = 0.5
    reconnect_max_s: float = 10.0


FOLLOW_MODEL = "model"
"""``scene.pads`` value meaning: the pads the serving model was trained on."""


@dataclass(frozen=True)
class SceneConfig:
    pads: str = "model"
    """Pads in contact: ``model`` (the serving model's own pads, so a model trained with any
    ``--pads`` serves) or a layout selection (``distal``, ``all``, ``1,3,5``, ...) that pins the
    scene: a model trained for other pads is then refused."""
    events: tuple[str, ...] = ("pull", "push", "hold", "bump")
    """Classes that are reported; other decisions are counted but not sent."""
    mode: str = "trigger"
    """``trigger`` (threshold starts a window) or ``continuous`` (needs a model with a dormant class)."""


@dataclass(frozen=True)
class ModelConfig:
    folder: str = "/var/lib/handover/models"
    poll_interval_s: float = 1.0
    max_bytes: int = 64 * 1024 * 1024
    decision_budget: float = 0.1
    """Longest a decision may take at warm-up, as a fraction of the model's sample period
    (0.1: 3.1 ms at 32 Hz); a slower model is refused."""
    quarantine_file: str | None = None
    """Where models taken out of service at run time are remembered across restarts; None: beside
    the health file (``quarantined-models.json``), or in memory only without one."""


@dataclass(frozen=True)
class TriggerConfig:
    """Unset (None) keys take the model's recorded trigger settings, else the default
    (runtime/trigger_settings.py, ``resolve_trigger``)."""

    kind: str | None = None
    """``onset`` (the person acts on a settled grasp) or ``threshold`` (the paper's fixed level)."""
    change: float | None = None
    """onset: a pad's change against the settled grasp that fires, as a share of it (default 0.12)."""
    track_tau_s: float | None = None
    """onset: time constant of the baseline following creep and drift (default 1 s)."""
    settle_s: float | None = None
    """onset: how long the grasp must be still before the trigger arms (default 0.2 s)."""
    fraction: float | None = None
    """threshold: level as a fraction of full scale; None takes the model's (else the paper's,
    ``trigger_settings.PAPER_FRACTION``)."""
    hysteresis: float | None = None
    """Re-arm only once the max drops below (fraction - hysteresis) of full scale; None takes the
    model's (else ``trigger_settings.DEFAULT_HYSTERESIS``)."""
    refractory_s: float = 1.5
    """No new trigger for this long after one (counted from the trigger frame): a pull or push
    goes on for up to about 1-1.5 s after its trigger, and one interaction is one event."""
    rearm_quiet_s: float = 0.25
    """Re-arm only after the level stayed below (fraction - hysteresis) this long: the pressure of
    a push wobbles and dips below the off level for a few frames (up to ~0.2 s) mid-interaction."""
    baseline: bool = False
    """Measure against a slowly tracked per-taxel baseline (the grasp itself may press the pads)."""
    baseline_tau_s: float = 2.0
    pre_frames: int | None = None
    """Frames before the trigger frame that belong to the window; None takes the model's (else 0)."""


@dataclass(frozen=True)
class ContinuousConfig:
    """The report rule of ``scene.mode = "continuous"`` (runtime/decision.py); chosen on a
    synthetic validation stream, see docs/DORMANT.md."""

    confirm_frames: int = 8
    """A non-dormant class is reported once it has won this many frames in a row."""
    min_margin: float = 0.0
    """... each with at least this score margin over the runner-up (0 = any win counts)."""
    rearm_frames: int = 4
    """After a report, the next one needs dormant to have won this many frames in a row
    (one report per interaction); 0 = report every change of the confirmed class."""


@dataclass(frozen=True)
class ControlConfig:
    socket: str | None = None
    """Unix datagram socket the daemon reads robot messages from (``grasp closed`` / ``grasp open``)."""


@dataclass(frozen=True)
class SinksConfig:
    stdout: bool = True
    udp: tuple[str, ...] = ()
    """``host:port`` targets for one JSON datagram per event."""
    unix: tuple[str, ...] = ()
    """Paths of Unix datagram sockets to send each event to."""
    ros2: bool = False
    """Publish events, health and (optionally) live pads on ROS 2 topics (``[ros2]``; the ``ros`` extra)."""

    @property
    def n_without_ros2(self) -> int:
        """How many sinks events reach when ROS 2 cannot start."""
        return int(self.stdout) + len(self.udp) + len(self.unix)


NO_SINK_LEFT = ("events go nowhere: no other sink is configured (set sinks.stdout = true, or add sinks.udp or "
                "sinks.unix targets)")
"""What to say when the only event sink is ROS 2 and it cannot start."""


RELIABILITIES = ("reliable", "best_effort")
DURABILITIES = ("volatile", "transient_local")


@dataclass(frozen=True)
class Ros2Config:
    """The ROS 2 sink (runtime/ros2_node.py); used only when ``sinks.ros2 = true``."""

    namespace: str = "/handover"
    """Topics: ``<namespace>/events``, ``<namespace>/model``, ``<namespace>/pads/<pad>``, ``<namespace>/grasp``."""
    node_name: str = "handover"
    reliability: str = "reliable"
    """QoS of the events and pads publishers (a reliable publisher also serves best-effort subscribers)."""
    durability: str = "volatile"
    """QoS of the events publisher; ``transient_local`` hands a late subscriber the last ``depth`` lines."""
    depth: int = 10
    """History depth of the events publisher (pads always keep only the newest image: drop, never queue)."""
    pads: bool = False
    """Publish each pad as a mono16 image on ``<namespace>/pads/<pad>``."""
    pad_rate_hz: float = 10.0
    """Images per second per pad at most (the newest frame; none when no new frame arrived)."""
    pad_gain: int = 1
    """Taxel values are multiplied by this in the images: 1 = raw 12-bit values; 16 spreads the
    12-bit full scale over mono16's range, so an image viewer shows the pads bright."""
    grasp: bool = False
    """Subscribe ``<namespace>/grasp`` (std_msgs/String ``closed`` / ``open``) from the robot's controller."""


@dataclass(frozen=True)
class OnnxConfig:
    intra_op_threads: int = 1
    allow_spinning: bool = False


@dataclass(frozen=True)
class Config:
    device: DeviceConfig = field(default_factory=DeviceConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    trigger: TriggerConfig = field(default_factory=TriggerConfig)
    continuous: ContinuousConfig = field(default_factory=ContinuousConfig)
    sinks: SinksConfig = field(default_factory=SinksConfig)
    onnxruntime: OnnxConfig = field(default_factory=OnnxConfig)
    ros2: Ros2Config = field(default_factory=Ros2Config)
    control: ControlConfig = field(default_factory=ControlConfig)
    log_level: str = "info"
    health_file: str | None = None
    realtime_priority: int = DEFAULT_PRIORITY
    """SCHED_FIFO priority of the hot path, 0 = normal scheduling (runtime.realtime says why)."""
    source: str = ""
    """Where the configuration was read from (for messages)."""
    warnings: tuple[str, ...] = ()
    """Things that are allowed but probably wrong (an event name no known model has)."""


# -- parsing --------------------------------------------------------------------------------


def load_config(path: str | Path) -> Config:
    """Read and validate a TOML file; raises ConfigError naming the file or the key."""
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: config file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read config file ({exc})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML ({exc})") from None
    cfg = config_from_dict(data)
    return _replace(cfg, source=str(p))


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build a Config from parsed TOML; raises ConfigError naming the first bad key.

    One reader a section, called in the file's order of sections, so the first bad key is the
    one reported."""
    if not isinstance(data, dict):
        raise ConfigError("config: must be a table")
    sections = {"device", "scene", "model", "trigger", "continuous", "sinks", "onnxruntime", "ros2", "control"}
    top = {"log_level", "health_file", "realtime_priority"}
    no_unknown("", data, sections | top)
    no_nul(data)
    for name in sections:
        if name in data and not isinstance(data[name], dict):
            raise ConfigError(f"{name}: must be a table ([{name}])")
    device = _device_config(data.get("device", {}))
    scene, warnings = _scene_config(data.get("scene", {}))
    model = _model_config(data.get("model", {}))
    trigger = _trigger_config(data.get("trigger", {}))
    continuous = _continuous_config(data.get("continuous", {}))
    sinks = _sinks_config(data.get("sinks", {}))
    ros2 = _ros2_config(data.get("ros2", {}))
    onnx_cfg = _onnx_config(data.get("onnxruntime", {}))
    control = _control_config(data.get("control", {}))
    log_level, health = _top_level(data)
    realtime = read_int("realtime_priority", data, DEFAULT_PRIORITY)
    return Config(device, scene, model, trigger, continuous, sinks, onnx_cfg, ros2, control, log_level, health,
                  realtime, warnings=tuple(warnings))


def _device_config(dev: dict) -> DeviceConfig:
    no_unknown("device", dev, {f.name for f in fields(DeviceConfig)})
    device = DeviceConfig(
        url=read_str("device.url", dev, DeviceConfig.url),
        stall_timeout_s=read_num("device.stall_timeout_s", dev, DeviceConfig.stall_timeout_s),
        reconnect_min_s=read_num("device.reconnect_min_s", dev, DeviceConfig.reconnect_min_s),
        reconnect_max_s=read_num("device.reconnect_max_s", dev, DeviceConfig.reconnect_max_s),
    )
    _check_url(device.url)
    if device.reconnect_max_s < device.reconnect_min_s:
        raise ConfigError("device.reconnect_max_s: must be >= device.reconnect_min_s")
    return device


def _scene_config(sc: dict) -> tuple[SceneConfig, list[str]]:
    """``[scene]`` and the warnings for event names no known model has."""
    no_unknown("scene", sc, {f.name for f in fields(SceneConfig)})
    pads = sc.get("pads", SceneConfig.pads)
    if isinstance(pads, list) and pads and all(isinstance(p, int) and not isinstance(p, bool) for p in pads):
        pads = ",".join(str(p) for p in pads)
    if not isinstance(pads, str) or not pads.strip():
        raise ConfigError(f"scene.pads: must be 'model' or a pad selection like 'distal' or [1, 3, 5], got {pads!r}")
    _check_pads(pads)
    events = read_str_list("scene.events", sc, SceneConfig.events)
    if not events:
        raise ConfigError("scene.events: must name at least one event")
    mode = read_str("scene.mode", sc, SceneConfig.mode)
    if mode not in MODES:
        raise ConfigError(f"scene.mode: must be one of {', '.join(MODES)}, got {mode!r}")
    pads = FOLLOW_MODEL if pads.strip().lower() == FOLLOW_MODEL else pads.strip()
    warnings = [
        f"scene.events: {e!r} is not a known event ({', '.join(KNOWN_EVENTS)}); "
        "it is reported only if the model has such a class"
        for e in events if e not in KNOWN_EVENTS
    ]
    return SceneConfig(pads=pads, events=events, mode=mode), warnings


def _model_config(mo: dict) -> ModelConfig:
    no_unknown("model", mo, {f.name for f in fields(ModelConfig)})
    return ModelConfig(
        folder=read_str("model.folder", mo, ModelConfig.folder),
        poll_interval_s=read_num("model.poll_interval_s", mo, ModelConfig.poll_interval_s),
        max_bytes=read_int("model.max_bytes", mo, ModelConfig.max_bytes),
        decision_budget=read_num("model.decision_budget", mo, ModelConfig.decision_budget),
        quarantine_file=None if "quarantine_file" not in mo else read_str("model.quarantine_file", mo, ""),
    )


def _trigger_config(tr: dict) -> TriggerConfig:
    no_unknown("trigger", tr, {f.name for f in fields(TriggerConfig)})
    fraction = read_optional_num("trigger.fraction", tr)
    if fraction is not None and not is_trigger_level(fraction):
        raise ConfigError(f"trigger.fraction: must be a number in (0, 1), got {fraction}")
    kind = tr.get("kind")
    if kind is not None and kind not in TRIGGER_KINDS:
        raise ConfigError(f"trigger.kind: must be one of {', '.join(TRIGGER_KINDS)}, got {kind!r}")
    trigger = TriggerConfig(
        kind=kind,
        change=read_optional_num("trigger.change", tr),
        track_tau_s=read_optional_num("trigger.track_tau_s", tr),
        settle_s=read_optional_num("trigger.settle_s", tr),
        fraction=fraction,
        hysteresis=read_optional_num("trigger.hysteresis", tr),
        refractory_s=read_num("trigger.refractory_s", tr, TriggerConfig.refractory_s),
        rearm_quiet_s=read_num("trigger.rearm_quiet_s", tr, TriggerConfig.rearm_quiet_s),
        baseline=read_bool("trigger.baseline", tr, TriggerConfig.baseline),
        baseline_tau_s=read_num("trigger.baseline_tau_s", tr, TriggerConfig.baseline_tau_s),
        pre_frames=None if "pre_frames" not in tr else read_int("trigger.pre_frames", tr, 0),
    )
    if fraction is not None and trigger.hysteresis is not None and trigger.hysteresis >= fraction:
        raise ConfigError(f"trigger.hysteresis: must be smaller than trigger.fraction ({fraction})")
    return trigger


def _continuous_config(co: dict) -> ContinuousConfig:
    no_unknown("continuous", co, {f.name for f in fields(ContinuousConfig)})
    return ContinuousConfig(
        confirm_frames=read_int("continuous.confirm_frames", co, ContinuousConfig.confirm_frames),
        min_margin=read_num("continuous.min_margin", co, ContinuousConfig.min_margin),
        rearm_frames=read_int("continuous.rearm_frames", co, ContinuousConfig.rearm_frames),
    )


def _sinks_config(si: dict) -> SinksConfig:
    no_unknown("sinks", si, {f.name for f in fields(SinksConfig)})
    udp = read_str_list("sinks.udp", si, ())
    for target in udp:
        parse_host_port(target, key="sinks.udp")
    unix = read_str_list("sinks.unix", si, ())
    for path in unix:
        if not path.startswith("/") and not path.startswith("@"):
            raise ConfigError(f"sinks.unix: socket path must be absolute, got {path!r}")
    return SinksConfig(stdout=read_bool("sinks.stdout", si, SinksConfig.stdout), udp=udp, unix=unix,
                       ros2=read_bool("sinks.ros2", si, SinksConfig.ros2))


def _onnx_config(ox: dict) -> OnnxConfig:
    no_unknown("onnxruntime", ox, {f.name for f in fields(OnnxConfig)})
    return OnnxConfig(
        intra_op_threads=read_int("onnxruntime.intra_op_threads", ox, OnnxConfig.intra_op_threads),
        allow_spinning=read_bool("onnxruntime.allow_spinning", ox, OnnxConfig.allow_spinning),
    )


def _control_config(ct: dict) -> ControlConfig:
    no_unknown("control", ct, {f.name for f in fields(ControlConfig)})
    sock = ct.get("socket")
    if sock is not None and (not isinstance(sock, str) or not (sock.startswith("/") or sock.startswith("@"))):
        raise ConfigError(f"control.socket: must be an absolute path or @abstract name, got {sock!r}")
    return ControlConfig(socket=sock)


def _top_level(data: dict) -> tuple[str, str | None]:
    """``log_level`` and ``health_file`` (its folder must exist)."""
    log_level = read_str("log_level", data, "info").lower()
    if log_level not in LOG_LEVELS:
        raise ConfigError(f"log_level: must be one of {', '.join(LOG_LEVELS)}, got {log_level!r}")
    health = data.get("health_file")
    if health is not None and (not isinstance(health, str) or not health.strip()):
        raise ConfigError(f"health_file: must be a path, got {health!r}")
    if health is not None:
        folder = Path(health).expanduser().parent
        if not folder.is_dir():
            raise ConfigError(f"health_file: folder {folder} does not exist (create it, or drop health_file)")
    return log_level, health


_ROS_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _ros2_config(table: dict) -> Ros2Config:
    """``[ros2]``: names as ROS 2 allows them, QoS names, rates; ConfigError naming the key."""
    no_unknown("ros2", table, {f.name for f in fields(Ros2Config)})
    namespace = read_str("ros2.namespace", table, Ros2Config.namespace)
    tokens = namespace.split("/")
    if not namespace.startswith("/") or not all(_ROS_TOKEN.fullmatch(t) for t in tokens[1:]):
        raise ConfigError(f"ros2.namespace: must look like /handover or /robot/hand (letters, digits, _), got {namespace!r}")
    node_name = read_str("ros2.node_name", table, Ros2Config.node_name)
    if not _ROS_TOKEN.fullmatch(node_name):
        raise ConfigError(f"ros2.node_name: letters, digits and _ (not starting with a digit), got {node_name!r}")
    reliability = read_str("ros2.reliability", table, Ros2Config.reliability)
    if reliability not in RELIABILITIES:
        raise ConfigError(f"ros2.reliability: must be one of {', '.join(RELIABILITIES)}, got {reliability!r}")
    durability = read_str("ros2.durability", table, Ros2Config.durability)
    if durability not in DURABILITIES:
        raise ConfigError(f"ros2.durability: must be one of {', '.join(DURABILITIES)}, got {durability!r}")
    return Ros2Config(
        namespace=namespace, node_name=node_name, reliability=reliability, durability=durability,
        depth=read_int("ros2.depth", table, Ros2Config.depth),
        pads=read_bool("ros2.pads", table, Ros2Config.pads),
        pad_rate_hz=read_num("ros2.pad_rate_hz", table, Ros2Config.pad_rate_hz),
        pad_gain=read_int("ros2.pad_gain", table, Ros2Config.pad_gain),
        grasp=read_bool("ros2.grasp", table, Ros2Config.grasp),
    )


def parse_host_port(target: str, key: str = "sinks.udp") -> tuple[str, int]:
    """``host:port`` (``[v6]:port`` too) -> (host, port); ConfigError naming the key otherwise."""
    host, sep, port = target.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"{key}: expected host:port, got {target!r}")
    return host, int(port)


# -- helpers --------------------------------------------------------------------------------


def _replace(cfg: Config, **changes: Any) -> Config:
    from dataclasses import replace

    return replace(cfg, **changes)



def _check_url(url: str) -> None:
    """The transports' own parser and scheme table: a URL that could never open is a config
    error here, not an endless "retrying" in the daemon. Nothing is opened."""
    from firmware_io.transports import TransportError, validate_url

    try:
        validate_url(url)
    except TransportError as exc:
        raise ConfigError(f"device.url: {exc}") from None


def _check_pads(pads: str) -> None:
    """Reject selections no layout could satisfy (the real check runs when the device reports its layout)."""
    from firmware_io.layout import LayoutError, SensorLayout

    if pads.strip().lower() == FOLLOW_MODEL:
        return
    try:
        SensorLayout.sdh2().pads(pads)
    except LayoutError as exc:
        if "no matrix" not in str(exc):  # indices are checked against the device's own layout later
            raise ConfigError(f"scene.pads: {exc}") from None
