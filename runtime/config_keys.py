"""Every key of the daemon's TOML config, declared once: name, type, range, default, one-line help.

``runtime.config`` reads every key from this table, ``runtime.trigger_settings`` takes the ``recorded``
trigger keys from it, and ``runtime.config_text`` writes deploy/handover.toml and docs/CONFIG.md from
it. Checks beyond a type and a range are ``runtime.config``'s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from firmware_io.trigger_level import PAPER_FRACTION
from runtime.realtime import DEFAULT_PRIORITY

__all__ = ["KEYS", "RANGES", "SECTIONS", "Key", "key", "section_keys"]


@dataclass(frozen=True)
class Key:
    """One config key. ``optional``: unset reads as None in the config (the model's recorded value,
    else ``default``, applies; or the feature is off); ``recorded``: a trigger setting a model records
    and is served with unless the config sets it; ``config=False``: recorded only, never in the file."""

    name: str
    """``section.key``, or ``key`` at the top level."""
    type: type
    """str, bool, int, float, or tuple (a list of strings)."""
    default: Any
    help: str
    range: tuple[float, float] | None = None
    """Closed range [lo, hi] of a number (bounded above too: an infinite or absurd value turns a
    safety mechanism off without an error)."""
    choices: tuple[str, ...] = ()
    optional: bool = False
    recorded: bool = False
    config: bool = True
    example: Any = None
    """A value to show instead of the default (deploy/handover.toml sets it when ``shown``, else
    names it in a comment)."""
    shown: bool = False

    @property
    def section(self) -> str:
        return self.name.rpartition(".")[0]

    @property
    def short(self) -> str:
        return self.name.rpartition(".")[2]

    @property
    def config_default(self) -> Any:
        """The config's value when the key is absent."""
        return None if self.optional else self.default


SECTIONS: dict[str, str] = {
    "": "",
    "device": "Where the DSACON32m is: serial:///dev/ttyUSB0, /dev/dsacon32m (udev symlink, see 99-handover.rules),\n"
              "tcp://192.168.1.42:13000 (SDH-2 Ethernet), usb://0403:6001, hid://10c4:ea80, sim:// (simulated hand).",
    "scene": "What the hand holds and what is reported.",
    "model": "The folder of models: the newest valid *.onnx serves; drop new ones as INSTALL.md says.",
    "trigger": "Unset keys take the settings the model was trained with (its metadata), else the defaults\n"
               "shown. Models trained before the onset trigger are served with the threshold.",
    "continuous": 'How scene.mode = "continuous" turns one decision per frame into one report per interaction\n'
                  "(docs/DORMANT.md; defaults chosen on synthetic validation streams, results/streams.md).",
    "sinks": "Where events go: one JSON line each (docs/EVENTS.md).",
    "onnxruntime": "One thread, no spinning: a flat latency tail on a busy core.",
    "ros2": "Used when [sinks] ros2 = true (needs the ros extra; deploy/INSTALL.md, section ROS 2).\n"
            "Topics: <namespace>/events (std_msgs/String, the JSON line of docs/EVENTS.md), <namespace>/model\n"
            "(latched: the model now serving), /diagnostics (the health view), <namespace>/pads/<pad>, <namespace>/grasp,\n"
            "<namespace>/arm, and the arm's motion from sensor_msgs/JointState on joint_states.",
    "control": 'Robot messages, one datagram each: "grasp closed" (the grasp has settled: the onset trigger arms at\n'
               'once), "grasp open" (the robot lets go: no event until the hand is empty or closed again),\n'
               '"arm moving" / "arm still" (no window is reported while the arm moves, nor arm_settle_s after).\n'
               "Without them the onset trigger finds the settled grasp itself. Anything else is counted and logged once.\n"
               'Send one with: echo -n "grasp closed" | socat - UNIX-SENDTO:/run/handover/control.sock\n'
               "or, without socat: python3 -c 'import socket; socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)"
               '.sendto(b"arm moving", "/run/handover/control.sock")\'',
    "capture": "Field capture (docs/GUIDE.md#field-capture): every decided window and a sample of idle stretches kept\n"
               "as recordings `handover train` reads, with the robot's outcomes (\"outcome taken\" on the control\n"
               "socket or <namespace>/outcome); the folder must be this user's (or root's) alone.",
}
"""The sections in the order they are read (the first bad key reported is the first in this order),
each with the note deploy/handover.toml and docs/CONFIG.md put above its keys."""

_S = 3600.0

KEYS: tuple[Key, ...] = (
    Key("log_level", str, "info", "what reaches the journal", choices=("debug", "info", "warning", "error")),
    Key("health_file", str, None, "JSON status, rewritten atomically about once a second (its folder must exist)",
        optional=True, example="/var/lib/handover/status.json", shown=True),
    Key("instance", str, None, "this daemon's name in every event and model line, the health file and /diagnostics "
        "(unset: <host>:<device>, e.g. robot-pc:dsacon32m; set it when two daemons share a listener)", optional=True,
        example="left-hand"),
    Key("realtime_priority", int, DEFAULT_PRIORITY,
        "SCHED_FIFO priority of the hot path (0 = normal scheduling); the unit's LimitRTPRIO=20 permits it",
        range=(0, 99)),

    Key("device.url", str, "serial:///dev/dsacon32m", "the device's URL (the schemes above)"),
    Key("device.stall_timeout_s", float, 2.0, "no frame for this long while streaming = stall: close and reconnect",
        range=(0.05, _S)),
    Key("device.reconnect_min_s", float, 0.5, "reconnect backoff doubles from min to max", range=(0.0, _S)),
    Key("device.reconnect_max_s", float, 10.0, "the longest wait between reconnects (>= reconnect_min_s)",
        range=(0.0, _S)),

    Key("scene.pads", str, "model", "pads in contact: model = the serving model's own pads; or pin them (distal, all, "
        "thumb, 1,3,5; a model trained for other pads is then refused)"),
    Key("scene.events", tuple, ("pull", "push", "hold", "bump"), "classes reported to the sinks (others are counted)"),
    Key("scene.mode", str, "trigger", "trigger: a window per trigger ([trigger]); continuous: a decision every frame "
        "(a model with a dormant class)", choices=("trigger", "continuous")),
    Key("scene.early_events", tuple, None, "events a model's early heads may report before the full window (unset: "
        "every event; [] never early; [\"pull\"]: let go at once on a pull, a bump may wait; docs/EARLY.md)",
        optional=True, example=["pull"]),

    Key("model.folder", str, "/var/lib/handover/models", "the newest valid *.onnx here serves"),
    Key("model.poll_interval_s", float, 1.0, "how often the folder is looked at", range=(0.01, _S)),
    Key("model.max_bytes", int, 64 * 1024 * 1024, "a larger model file is refused", range=(1024, 1 << 30)),
    Key("model.decision_budget", float, 0.1, "a model whose warm-up decision takes longer than this fraction of its "
        "sample period (3.1 ms at 32 Hz) is refused", range=(0.001, 1.0)),
    Key("model.quarantine_file", str, None, "models taken out of service, remembered across restarts (unset: beside "
        "health_file, or in memory only without one)", optional=True,
        example="/var/lib/handover/quarantined-models.json"),
    Key("model.shadow", str, None, "a folder for a candidate model: it runs on the serving model's windows off the hot "
        "path, its decisions go out as shadow lines, the health view compares the two (docs/GUIDE.md, A candidate in "
        "shadow); never model.folder", optional=True, example="/var/lib/handover/shadow"),

    Key("trigger.kind", str, "onset", "onset: the person acts on the settled grasp (chosen in results/streams.md); "
        "threshold: the paper's fixed level", choices=("onset", "threshold"), optional=True, recorded=True),
    # How the onset defaults were chosen: docs/TRIGGER_DEFAULTS.md.
    Key("trigger.change", float, 0.12, "onset: a pad departing by this share of the settled grasp fires",
        range=(0.001, 0.99), optional=True, recorded=True),
    Key("trigger.track_tau_s", float, 1.0, "onset: the baseline follows slower changes (creep, drift)",
        range=(0.05, 600.0), optional=True, recorded=True),
    Key("trigger.settle_s", float, 0.2, "onset: the grasp must be still this long before the trigger arms",
        range=(0.0, 60.0), optional=True, recorded=True),
    Key("trigger.fraction", float, PAPER_FRACTION, "threshold: the level, of full scale (the paper: 15 %; open "
        "range: 0 fires always, 1 never)", range=(0.0, 1.0), optional=True, recorded=True),
    Key("trigger.hysteresis", float, 0.05, "threshold: re-arm below (fraction - hysteresis) of full scale",
        range=(0.0, 0.99), optional=True, recorded=True),
    Key("trigger.refractory_s", float, 1.5, "no new trigger this soon after one: a pull or push goes on for up to "
        "1-1.5 s after its trigger (one interaction, one event)", range=(0.0, _S)),
    Key("trigger.rearm_quiet_s", float, 0.25, "threshold: re-arm only after the level stayed below the re-arm level "
        "this long (a push's pressure wobbles and dips for a few frames)", range=(0.0, 60.0)),
    Key("trigger.baseline", bool, False, "threshold: true = measure above a slowly tracked per-taxel baseline (for "
        "grasps that already press the pads)"),
    Key("trigger.baseline_tau_s", float, 2.0, "threshold: time constant of that baseline", range=(0.01, 86400.0)),
    Key("trigger.pre_frames", int, 0, "frames before the trigger frame that belong to the window",
        range=(0, 1000), optional=True, recorded=True),
    Key("trigger.back_frames", int, 3, "onset: a window starts where its departure began (the first frame of its "
        "unbroken stretch at or above half of change), at most this many frames before the trigger frame and at most "
        "T - 1 - pre_frames (a model recording none was cut at the trigger frame)",
        range=(0, 1000), recorded=True, config=False),
    Key("trigger.floor", float, 0.25, "onset: changes are measured against at least this x full scale of summed "
        "pressure (an unloaded pad must gain a real contact)", range=(0.001, 1.0), recorded=True, config=False),
    Key("trigger.contact", float, 0.02, "onset: summed scene pressure below this x full scale is an empty hand",
        range=(0.0, 1.0), recorded=True, config=False),
    Key("trigger.settle_change", float, 0.02, "onset: settled = no pad changed by this share of its level from one "
        "frame to the next for settle_s (or by less than twice this for three times settle_s: a noisy hand)", range=(0.0, 1.0), recorded=True, config=False),

    Key("continuous.confirm_frames", int, 10, "a class is reported after winning this many frames in a row",
        range=(1, 1000)),
    Key("continuous.min_margin", float, 0.0, "... each by this score margin over the runner-up (0 = any win)",
        range=(0.0, 1000.0)),
    Key("continuous.rearm_frames", int, 16, "next report only after dormant won this many frames in a row (0 = report "
        "every change of the confirmed class)", range=(0, 100000)),
    Key("continuous.gap_frames", int, 1, "dormant frames in a row that do not break a run (a hold flickers with "
        "dormant)", range=(0, 1000)),
    Key("continuous.vote", bool, False, "true: a run is any non-dormant class; the class that won most of its frames "
        "is reported"),

    Key("sinks.stdout", bool, True, "JSON lines on stdout (journald)"),
    Key("sinks.udp", tuple, (), "host:port targets, one JSON datagram per event", example=("127.0.0.1:5005",)),
    Key("sinks.unix", tuple, (), "absolute paths (or @abstract names) of Unix datagram sockets",
        example=("/run/handover/events.sock",)),
    Key("sinks.ros2", bool, False, "true: also publish on ROS 2 topics ([ros2]; the ros extra)"),

    Key("onnxruntime.intra_op_threads", int, 1, "threads of one decision", range=(1, 64)),
    Key("onnxruntime.allow_spinning", bool, False, "let idle threads spin (costs a core)"),

    Key("ros2.namespace", str, "/handover", "the topics' prefix (/handover, /robot/hand: letters, digits, _)"),
    Key("ros2.node_name", str, "handover", "letters, digits and _ (not starting with a digit)"),
    Key("ros2.reliability", str, "reliable", "QoS of events and pads (a reliable publisher serves best-effort "
        "subscribers too)", choices=("reliable", "best_effort")),
    Key("ros2.durability", str, "volatile", "QoS of events; transient_local hands a late subscriber the last `depth` "
        "events", choices=("volatile", "transient_local")),
    Key("ros2.depth", int, 10, "history depth of the events publisher (pads keep only the newest image)",
        range=(1, 10000)),
    Key("ros2.pads", bool, False, "true: each pad as sensor_msgs/Image mono16 on <namespace>/pads/<pad>"),
    Key("ros2.pad_rate_hz", float, 10.0, "images per second per pad at most (the newest frame; never queued)",
        range=(0.1, 1000.0)),
    Key("ros2.pad_gain", int, 1, "taxel value x this in the images (16: 12-bit full scale = mono16 white)",
        range=(1, 16)),
    Key("ros2.grasp", bool, False, 'true: listen on <namespace>/grasp ("closed" / "open") from the robot'),
    Key("ros2.arm", bool, False, 'true: listen on <namespace>/arm ("moving" / "still") from the robot'),
    Key("ros2.outcome", bool, False, 'true: listen on <namespace>/outcome ("taken" / "kept" / "dropped" / a class '
        "name) from the robot ([capture])"),
    Key("ros2.joint_states", str, None, "sensor_msgs/JointState topic: the arm counts as moving while a joint's speed "
        "exceeds joint_speed (runtime/arm_motion.py)", optional=True, example="/joint_states"),
    Key("ros2.joint_speed", float, 0.05, "rad/s (or m/s): a joint faster than this moves the arm", range=(1e-6, 100.0)),
    Key("ros2.trust", str, "sros2", "who may send grasp, arm and joint_states: sros2 = only with SROS2 enforced; "
        "local_users = also without SROS2 with discovery kept to this PC (every user of this PC); network = any ROS 2 "
        "node in the domain", choices=("sros2", "local_users", "network")),

    Key("control.socket", str, None, "Unix datagram socket (absolute path or @abstract name) for robot messages",
        optional=True, example="/run/handover/control.sock"),
    Key("control.arm_settle_s", float, 0.5, "after 'arm still' the arm counts as moving this long (the object rings "
        "on the fingers after the stop; runtime/arm_motion.py)", range=(0.0, 60.0)),
    Key("control.arm_max_move_s", float, 30.0, "'arm moving' holds this long unless repeated (a lost 'arm still' "
        "must not deafen the daemon)", range=(0.1, _S)),

    Key("capture.folder", str, None, "absolute path of the capture folder (unset: nothing is kept); created if "
        "missing", optional=True, example="/var/lib/handover/field"),
    Key("capture.max_mb", float, 1024.0, "the folder's recordings, outcomes and labels stay below this many MB (the "
        "oldest recordings are removed first)", range=(1.0, 1e7)),
    Key("capture.idle_every_s", float, 600.0, "at most one idle stretch kept per this many seconds of device time "
        "with no decided window (0: none)", range=(0.0, 86400.0)),
)
"""Every key, section by section in the order of ``SECTIONS``."""

_BY_NAME = {k.name: k for k in KEYS}

RANGES: dict[str, tuple[float, float]] = {k.name: k.range for k in KEYS if k.range is not None and k.config}
"""Every number of the config and its closed range [lo, hi] (``trigger.fraction`` is open at both ends:
its own check)."""


def key(name: str) -> Key:
    """The declaration of ``name`` (``section.key``)."""
    return _BY_NAME[name]


def section_keys(section: str, config_only: bool = True) -> tuple[Key, ...]:
    """The keys of one section (``""``: the top level) in declared order."""
    return tuple(k for k in KEYS if k.section == section and (k.config or not config_only))
