"""SIGHUP: reload the config file and apply it, or keep the running one if the new one is invalid
(mixed into ``runtime.daemon.Daemon``).

Called by the main loop only between windows (never between a trigger and its window's end).
Only what changed is rebuilt: sinks always, the control socket, health file, device link and
model watcher when their sections changed, and the ring and trigger for the new scene.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from typing import Any

from runtime.config import Config, ConfigError, load_config
from runtime.health import Health, StatusFile, one_line
from runtime.retry_notes import RetryNotes
from runtime.scene import scene_problem
from runtime.sdnotify import Notifier
from runtime.sinks import SinkSet

log = logging.getLogger("handover.daemon")


def changed_sections(old: Config, new: Config) -> str:
    """``changed: sinks, trigger`` (the config's tables and top-level keys that differ), or
    ``nothing changed``: what an operator wants to read after a SIGHUP."""
    names = [f.name for f in dataclasses.fields(new)
             if f.name not in ("source", "warnings") and getattr(new, f.name) != getattr(old, f.name)]
    return "changed: " + ", ".join(names) if names else "nothing changed"


class ConfigReload:
    """Applies a reloaded config to the running daemon."""

    cfg: Config
    health: Health
    notifier: Notifier
    sinks: SinkSet
    stream: Any
    status_file: StatusFile | None
    control: Any
    client: Any
    layout: Any
    model: Any
    watcher: Any
    _reload: bool
    _next_connect: float
    retry_notes: RetryNotes
    start_control: Callable[[], None]
    stop_control: Callable[[], None]
    _close_client: Callable[..., None]
    _start_watcher: Callable[[], None]
    _build_hot_path: Callable[..., None]

    def _do_reload(self) -> None:
        self._reload = False
        source = self.cfg.source
        if not source:
            log.warning("SIGHUP: no config file to reload")
            return
        self.notifier.reloading()
        try:
            new = load_config(source)
        except Exception as exc:  # a ConfigError, or any bug in a check: never fatal to a running daemon
            reason = one_line(exc) if isinstance(exc, ConfigError) else f"{type(exc).__name__}: {one_line(exc)}"
            log.error("SIGHUP: %s; keeping the running configuration", reason)
            self.health.report_error(f"reload refused: {reason}", "config")
            self.notifier.ready(self.health.status_line())
            return
        old, self.cfg = self.cfg, new
        set_log_level(new.log_level)
        for warning in new.warnings:
            log.warning("%s", warning)
        self.sinks.close()
        self.sinks = SinkSet.from_config(new.sinks, self.stream, ros2=new.ros2, daemon=self)
        if new.control != old.control or self.control is None:  # also retries one that could not bind
            self.stop_control()
            self.start_control()
        if new.realtime_priority != old.realtime_priority:
            self.apply_scheduling()
        if new.health_file != old.health_file:
            self.status_file = StatusFile(new.health_file) if new.health_file else None
        if new.device.url != old.device.url:
            self._close_client()
            self.client = None
            self.layout = None
            self._next_connect = 0.0
            self.retry_notes.reset()
        if new.scene != old.scene or new.model != old.model or new.onnxruntime != old.onnxruntime:
            self._refit_model(old, new)
        self._build_hot_path(keep_history=new.scene == old.scene)
        self.health.resolve("config")
        log.info("configuration reloaded from %s (%s)", source, changed_sections(old, new))
        self.notifier.ready(self.health.status_line())

    def _refit_model(self, old: Config, new: Config) -> None:
        """The new scene may not fit the model in use; new model settings restart the watcher."""
        if self.model is not None and scene_problem(self.model, new, self.layout):
            log.warning("the model in use does not fit the new scene; waiting for one that does")
            self.model = None
            self.health.model_id = None
        if new.model != old.model or new.onnxruntime != old.onnxruntime:
            self._start_watcher()
        elif self.watcher is not None:  # a file rejected under the old scene may fit the new one
            self.watcher.rescan(keep_current=self.model is not None)


def set_log_level(level: str) -> None:
    logging.getLogger("handover").setLevel(level.upper())
