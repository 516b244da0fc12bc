"""``handover run --config FILE [--check [--require-model]]``: the detection daemon (systemd service).

``--check`` validates the config and the model the daemon would serve without opening the device:
exit 2 for a config error, 0 otherwise (an empty model folder is only a warning, as the daemon waits
for a model; ``--require-model`` makes it exit 1). The daemon exits 0 after SIGTERM, 2 when the device
URL or the control socket can never work, 3 when a model's decision did not stop (runtime.decision_guard).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path

from firmware_io.errors import HandoverError

__all__ = ["add_arguments", "main"]

PROG = "handover run"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE", help="TOML configuration (see deploy/handover.toml)")
    parser.add_argument("--check", action="store_true", help="validate the config and the model folder, then exit")
    parser.add_argument("--require-model", action="store_true",
                        help="with --check: exit 1 when no model in the folder would serve (default: a warning)")
    parser.add_argument("--device", action="store_true",
                        help="with --check: also open the device for a few seconds and report frames and rate "
                             "(exit 1 when it gives none)")


def main(args: argparse.Namespace) -> int:
    from runtime.config import load_config

    if args.device and not args.check:
        raise HandoverError("--device goes with --check (handover run --config FILE --check --device)")
    cfg = load_config(args.config)  # a ConfigError, like every refusal below, is handover's one line and exit 2
    handler = logging.StreamHandler(sys.stderr)
    formatter = logging.Formatter(log_format(), datefmt="%Y-%m-%dT%H:%M:%S")
    formatter.converter = time.gmtime
    handler.setFormatter(formatter)
    logging.basicConfig(handlers=[handler])
    logging.getLogger("handover").setLevel(cfg.log_level.upper())
    if args.check:
        code = _check(cfg, require_model=args.require_model)
        print(CHECKED)
        print(NOT_CHECKED_WITH_DEVICE if args.device else NOT_CHECKED, flush=True)
        device_code = _check_device(cfg) if args.device else 0  # the device's verdict comes last, not buried
        return code or device_code
    from runtime import instance_lock

    locks = instance_lock.Locks.take(cfg)  # before anything is opened or written: a second daemon leaves the first one's files alone
    from runtime.daemon import Daemon
    from runtime.sinks import claim_stdout_for_events

    try:
        daemon = Daemon(cfg, stream=claim_stdout_for_events())  # only event lines reach stdout
        daemon.locks = locks  # a reload to another device or health file moves them
        daemon.start_capture()  # a capture folder another user could write to: one line, exit 2
        try:
            daemon.start_control()
        except OSError as exc:
            raise HandoverError(str(exc)) from None
        daemon.install_signal_handlers()
        code = daemon.run()
        if daemon.fatal:
            print(f"{PROG}: {daemon.fatal}", file=sys.stderr)
        return code
    finally:
        locks.release()


def log_format(environ: dict | None = None) -> str:
    """journald stamps each line itself (it sets JOURNAL_STREAM for the service's stderr);
    anywhere else a line carries its own UTC time."""
    env = os.environ if environ is None else environ
    if env.get("JOURNAL_STREAM"):
        return "%(levelname)s %(name)s: %(message)s"
    return "%(asctime)s.%(msecs)03dZ %(levelname)s %(name)s: %(message)s"


def _check(cfg, require_model: bool = False) -> int:
    """Report what the daemon would serve, without opening the device."""
    models_log = logging.getLogger("handover.models")
    level = models_log.level
    models_log.setLevel(logging.CRITICAL)  # --check reports in one line itself
    try:
        return _check_quietly(cfg, require_model)
    finally:  # called in-process (tests, scripts): the watcher's log is the caller's again
        models_log.setLevel(level)


def _check_quietly(cfg, require_model: bool) -> int:
    from runtime.capture_writer import folder_unwritable
    from runtime.health import Health
    from runtime.model_serving import ModelSlot
    from runtime.model_watch import ModelWatcher, folder_problem
    from runtime.scene import events_problem, scene_problem

    problem = (_missing_folder(cfg) or folder_problem(cfg.model.folder)
               or (cfg.model.shadow and folder_problem(cfg.model.shadow, "model.shadow")) or _pads_problem(cfg.scene.pads)
               or _control_problem(cfg) or _lock_problem(cfg) or _capture_problem(cfg))
    if problem:
        raise HandoverError(problem)
    _warn_about_sinks(cfg)
    for line in _held(cfg):
        print(f"{PROG}: warning: {line}; a second daemon on it would exit 2", file=sys.stderr)
    if cfg.capture.folder and (line := folder_unwritable(cfg.capture.folder)):
        print(f"{PROG}: warning: {line}", file=sys.stderr)
    slot = ModelSlot(cfg, Health(), serve=lambda _: None, announce=lambda _: None)

    def newest(check_events: bool):
        watcher = ModelWatcher(cfg.model.folder, loader=slot.load,
                               check=lambda m: scene_problem(m, cfg, None, check_events=check_events),
                               decision_budget=cfg.model.decision_budget, quarantine=slot.quarantine)
        return watcher.poll(require_stable=False), watcher.rejections, watcher.unreadable_names

    model, rejections, unreadable = newest(check_events=True)
    if model is None and rejections:
        # A model that fits everything but an event name means a typo in scene.events (a
        # config problem), not a reason to wait for another model.
        fits_otherwise, _, _ = newest(check_events=False)
        if fits_otherwise is not None:
            raise HandoverError(events_problem(fits_otherwise, cfg.scene.events))
    for warning in cfg.warnings:
        print(f"{PROG}: warning: {warning}", file=sys.stderr)
    if model is not None:
        for r in rejections:  # tried first, so dropped after the one that would serve: say why it would not
            print(f"{PROG}: warning: {r.path.name} (dropped later) would be refused: {r.reason}", file=sys.stderr)
        if model.early_note:
            print(f"{PROG}: warning: {model.early_note}", file=sys.stderr)
        for line in _cost_lines(cfg, model):
            print(f"{PROG}: warning: {line}", file=sys.stderr)
        print(f"config {cfg.source} is valid; would serve model {model.model_id} ({model.path.name})")
        return 0
    reasons = "; ".join([*(f"{r.path.name}: {r.reason}" for r in rejections),
                         *(f"{name!r}: control characters in its name (rename it)" for name in sorted(unreadable))]) \
        or "no .onnx file"
    what = f"no model in {cfg.model.folder} would serve yet ({reasons})"
    if require_model:
        print(f"{PROG}: config {cfg.source} is valid, but {what}", file=sys.stderr)
        return 1
    print(f"{PROG}: warning: {what}; the daemon will wait for one", file=sys.stderr)
    print(f"config {cfg.source} is valid")
    return 0


def _cost_lines(cfg, model) -> list[str]:
    """The served setting's line when its false events on real idle signals are unmeasured or too many
    (runtime.stream_settings.cost_lines); the setting is the config's scene mode and trigger in force."""
    from runtime.stream_settings import cost_lines, served_setting
    from runtime.trigger_settings import resolve_trigger

    kind = resolve_trigger(cfg.trigger, model.meta.trigger).kind
    return cost_lines(model.meta, [served_setting(model.meta.dormant_class, kind, cfg.scene.mode)])


def _warn_about_sinks(cfg) -> None:
    """One warning when ROS 2 cannot start (and events would then go nowhere) or no sink is set."""
    from runtime.config import NO_SINK_LEFT

    others = cfg.sinks.n_without_ros2
    if cfg.sinks.ros2:
        from runtime.ros2 import availability_problem, robot_inputs

        if problem := availability_problem():
            then = "events will go to the other sinks only" if others else NO_SINK_LEFT
            print(f"{PROG}: warning: sinks.ros2: {problem}; {then}", file=sys.stderr)
        if line := robot_inputs(cfg.ros2)[1]:
            print(f"{PROG}: warning: {line}", file=sys.stderr)
    elif not others:
        print(f"{PROG}: warning: sinks: {NO_SINK_LEFT.replace('other ', '')}", file=sys.stderr)
    _warn_about_udp_hosts(cfg)


def _warn_about_udp_hosts(cfg) -> None:
    """A UDP sink whose host name does not resolve: the daemon runs and sends there once it does."""
    from runtime.config import parse_host_port
    from runtime.name_resolver import resolve_problem

    for target in cfg.sinks.udp:
        host, port = parse_host_port(target)
        if problem := resolve_problem(host, port):
            print(f"{PROG}: warning: sinks.udp: {target}: the host name does not resolve ({problem}); the daemon "
                  "sends events there once it does", file=sys.stderr)


CHECKED = ("checked: config keys and values; the device URL's form; the model folder and the model that would "
           "serve (its contract, pads, classes against scene.events, a warm-up decision); scene.pads; the packages "
           "the sinks need; that the UDP sinks' host names resolve; the control socket's path and that no other "
           "process holds it; that the capture folder is this user's alone and writable; that no other daemon holds this device or health file")
NOT_CHECKED = ("not checked: the device itself (add --device to open it for a few seconds); whether the UDP and Unix "
               "destinations listen; who sends on the control socket; the real-time priority")
NOT_CHECKED_WITH_DEVICE = NOT_CHECKED.replace("the device itself (add --device to open it for a few seconds); ", "")
"""What ``--check`` looked at and what it did not, said after the config's verdict (a valid config is not a working
daemon) and before the device's (with ``--device``, the last thing on screen)."""


def _check_device(cfg) -> int:
    """Open the device for a few seconds (``runtime.device_check``): 0 when frames came, else 1 (one line).
    A device another daemon holds is not opened: reading it would take it from that daemon."""
    from runtime.device_check import probe_device

    if held := next((line for line in _held(cfg) if line.startswith("device ")), None):
        print(f"{PROG}: {held}; not opened (stop that daemon to check the device)", file=sys.stderr)
        return 1
    print(f"opening {cfg.device.url} ...", flush=True)  # how long it reads is said once the controller answered
    probe = probe_device(cfg.device.url, on_wait=lambda line: print(f"device {line}", flush=True))
    if probe.problem:
        print(f"{PROG}: {probe.line()}", file=sys.stderr)
        return 1
    print(probe.line())
    return 0


def _held(cfg) -> list[str]:
    """A line for each lock of ``cfg`` another daemon holds (checking the running service's config is normal)."""
    from runtime import instance_lock

    return [line for what, path in instance_lock.targets(cfg) if (line := instance_lock.held_by_other(what, path))]


def _lock_problem(cfg) -> str | None:
    """A lock ``run`` could not take (a symbolic link, a FIFO, a read-only folder), or a health file it
    could not write (runtime.health.write_problem, as ``Locks.take`` asks): ``run`` would exit 2."""
    from runtime import instance_lock
    from runtime.health import write_problem

    return next((line for what, path in instance_lock.targets(cfg) if (line := instance_lock.problem(what, path))),
                None) or (write_problem(cfg.health_file) if cfg.health_file else None)


def _control_problem(cfg) -> str | None:
    """A ``control.socket`` that can never be bound, or that another process holds while no daemon of
    this config runs (the running service holds its own): the daemon would refuse to start."""
    from runtime import control_access

    address = cfg.control.socket
    if not address:
        return None
    if problem := control_access.socket_path_problem(address):
        return problem
    return control_access.in_use_line(address) if control_access.held(address) and not _held(cfg) else None


def _capture_problem(cfg) -> str | None:
    """A capture folder the daemon would refuse (another user's, not a folder): ``run`` would exit 2."""
    from runtime.capture_writer import folder_problem

    return folder_problem(cfg.capture.folder) if cfg.capture.folder else None


def _missing_folder(cfg) -> str | None:
    """A model folder that does not exist is a typo or a missed install step, so --check calls it an
    error (an existing empty folder is only a warning; the running daemon waits for either)."""
    for key, value in (("model.folder", cfg.model.folder), ("model.shadow", cfg.model.shadow)):
        folder = Path(value or ".")
        if not (folder.exists() or folder.is_symlink()):
            return f"{key} {folder} does not exist: create it (mkdir -p {folder}) or fix the path in {cfg.source}"
    return None


def _pads_problem(pads: str) -> str | None:
    """A pad selection the SDH-2 cannot satisfy (``1,3,9``: it has matrices 0-5): the daemon would
    reject every model and classify nothing, so --check calls it an error."""
    from firmware_io.layout import LayoutError, SensorLayout
    from runtime.config import FOLLOW_MODEL

    if pads == FOLLOW_MODEL:  # the model's own pads: nothing to check before a model is there
        return None
    layout = SensorLayout.sdh2()
    try:
        layout.pads(pads)
    except LayoutError as exc:
        return f"scene.pads: {exc} (the SDH-2 has matrices 0-{layout.n_matrices - 1})"
    return None
