"""The detection service: one ``Detector`` and the narrow parts around it.

The parts, each with its own module (composed as python-can composes a Bus, a Notifier and Listeners):

- ``Detector`` (runtime.detector): frames in, decisions out; no I/O;
- ``DeviceLink`` (runtime.device_link): the device client, connect with backoff, faults, stalls;
- ``ModelSlot`` (runtime.model_serving): the model folder's watcher and quarantine, swaps, fallback;
- ``Reporter`` (runtime.reporter): decisions counted, event lines to the sinks;
- ``ControlSocket`` (runtime.control) and the ROS 2 node: the robot's words, from their own threads,
  through ``RobotInputs`` (queued for the next frame; an outcome goes to field capture);
- ``FieldCapture`` (runtime.capture): a listener keeping decided windows and idle, written by its own thread;
- ``Health`` and ``StatusFile`` (runtime.health), ``Notifier`` (runtime.sdnotify), ``HotThread``
  (runtime.realtime).

Each part keeps its own state and counters (``Health`` composes them) and reports by return values;
only the daemon changes the detector (``_apply``). One thread runs the hot path (read a frame,
``Detector.feed``, ``Reporter.report``); everything slow (model loading, the health file, reconnects,
SIGHUP reloads) happens on other threads or between frames.
"""

from __future__ import annotations

import logging
import signal
import time
from collections.abc import Callable
from typing import IO, TYPE_CHECKING, Any

from firmware_io.layout import SensorLayout
from runtime.capture import FieldCapture
from runtime.capture_writer import CaptureError, CaptureWriter
from runtime.config import Config, ConfigError, load_config
from runtime.config_reload import changed_sections, set_log_level
from runtime.control import ControlSocket, MessageLog
from runtime.decision_guard import DecisionGuard
from runtime.detector import Decision, Detector
from runtime.device_link import DeviceLink, Linked
from runtime.health import Health, StatusFile, one_line
from runtime.heap import settle_heap
from runtime.instance_name import instance_of
from runtime.listeners import FrameListener
from runtime.model_serving import ModelSlot
from runtime.realtime import HotThread
from runtime.rehearsal import RehearsedReads
from runtime.reporter import Reporter
from runtime.scene import events_problem, scene_problem
from runtime.sdnotify import Notifier
from runtime.shadow import Shadow
from runtime.sinks import DaemonSide, Event, ModelAnnouncement, SinkSet

if TYPE_CHECKING:
    from firmware_io.client import Frame
    from runtime.model import LoadedModel

__all__ = ["Daemon", "events_problem", "scene_problem"]  # the last two are re-exported for run --check

log = logging.getLogger("handover.daemon")

READ_TIMEOUT_S = 0.1
"""Longest the loop blocks on the device: bounds the reaction to SIGTERM and the watchdog."""
HEALTH_PERIOD_S = 1.0
HOLD_LIMIT_S = 10.0
"""How long open windows may hold back a model swap or a reload (``Daemon.windows_hold``); longer
for a stream so slow that two windows take longer."""
_KEEP: Any = object()
"""``Daemon._apply``'s model when the serving model stays."""
SHUTDOWN_STOP_S = 0.3
"""Longest the stop handshake may take at shutdown (SIGTERM must end the process within 1 s)."""


class RobotInputs:
    """The robot's grasp and arm words, from the control socket's or the ROS 2 node's thread: queued in the
    detector for its next frame (no lock on the hot path), each kind logged at most every few seconds; its
    outcomes go to field capture (``capture``, set by the daemon)."""

    def __init__(self, detector: Detector) -> None:
        self._detector, self._messages = detector, MessageLog()
        self.capture: FieldCapture | None = None
        self.shadow: Shadow | None = None
        """Judges its candidate and the serving model by each outcome field capture takes (set by the daemon)."""
        self.outcomes_ignored = 0
        """Outcomes heard while capture is off (the first is logged)."""

    def outcome(self, word: str, source: str = "") -> None:
        """The robot's word about its last event (``outcome taken``): kept by field capture, if on."""
        capture = self.capture
        if capture is not None:
            if capture.outcome(word, source) and self.shadow is not None:
                self.shadow.outcome(word)  # the same event: both are about the newest reported window
            return
        self.outcomes_ignored += 1
        if self.outcomes_ignored == 1:
            log.warning("outcome %r from %s ignored: [capture] folder is not set (further ones are only counted)",
                        word[:40], source or "the robot")

    def set_grasp(self, closed: bool, source: str = "") -> None:
        """The grasp has settled (``closed``) or is released; ``source`` names the caller in the log."""
        self._detector.set_grasp(closed, source)
        self._messages.note("grasp", "closed" if closed else "open", source)

    def set_arm_moving(self, moving: bool, source: str = "") -> None:
        """The arm moves or has stopped (runtime.arm_motion: no window is reported meanwhile and while it settles)."""
        self._detector.set_arm_moving(moving, source)
        self._messages.note("arm", "moving" if moving else "still", source)


class Daemon:
    """The long-running service (module docstring). ``run()`` returns the exit code."""

    def __init__(
        self,
        cfg: Config,
        notifier: Notifier | None = None,
        stream: IO[str] | None = None,
        client_factory: Callable[[str], Any] | None = None,
        on_event: Callable[[Event], None] | None = None,
    ) -> None:
        self.cfg = cfg
        self.notifier = notifier or Notifier()
        self.stream = stream
        self.health = Health()
        self.health.instance = instance_of(cfg)
        self.status_file: StatusFile | None = StatusFile(cfg.health_file) if cfg.health_file else None
        self.detector = Detector.from_config(cfg, self.health)
        self.listeners: list[FrameListener] = []
        """Called with every frame handled and every decision's stage timings (runtime.listeners);
        benchmarks and tests observe the real hot path through them. Empty: one list check per frame."""
        self.robot = RobotInputs(self.detector)
        """The grasp and arm commands the control socket and the ROS 2 node may give, from their threads."""
        self.reporter = Reporter(self._sinks(cfg), on_event, self.listeners)
        self.models = ModelSlot(cfg, self.health, self._apply, self._announce)
        self.shadow = Shadow(cfg, self.health, self.models.load, self.models.problem, self.models.quarantine,
                             lambda: self.detector.model, lambda line: self.sinks.emit(line))
        """A candidate model in shadow (``[model] shadow``): fed each decided window, off the hot thread."""
        self.robot.shadow = self.shadow
        self.link = DeviceLink(cfg.device, self.health, self.notifier, client_factory)
        self.frames_received = 0
        self._control_ignored = 0
        self.health.parts = [self._counters, self.link.counters, self.detector.counters, self.models.counters,
                             self.reporter.counters, self.shadow.counters]
        self.link.scene = cfg.scene.pads
        self.control: ControlSocket | None = None
        self.capture: FieldCapture | None = None
        """Field capture (``[capture] folder``), started with the daemon (``start_capture``)."""
        self.health.parts.append(lambda: self.capture.counters() if self.capture is not None else {})
        self.locks: Any = None
        """The instance locks ``handover run`` took (runtime.instance_lock.Locks): a reload moves them."""
        self.hot_thread = HotThread()
        self.guard = DecisionGuard(lambda: self.detector.model, self.detector.frame_clock.deadline_s,
                                   on_stuck=self._stuck, priority=cfg.realtime_priority)
        """Ends a decision that runs past the stream's period, from its own thread (runtime.decision_guard)."""
        self._stop = False
        self._reload = False
        self._held_since: float | None = None
        """Since when open windows have held back a model swap or a reload (``windows_hold``)."""
        self._next_health = 0.0

    # -- what other parts and embedders call ----------------------------------------------------------
    @property
    def sinks(self) -> SinkSet:
        return self.reporter.sinks

    @property
    def model(self) -> LoadedModel | None:
        """The serving model (the detector's), or None."""
        return self.detector.model

    @property
    def layout(self) -> SensorLayout | None:
        """The device's layout as the detector has it (None before a device streams)."""
        return self.detector.layout

    @property
    def fatal(self) -> str | None:
        """Why the daemon gave up (a device URL that can never open, a missing package), or None."""
        return self.link.fatal

    def serve(self, model: LoadedModel, layout: SensorLayout) -> None:
        """Serve ``model`` for a device with ``layout``, fed by the caller through ``handle_frame`` (no
        device, no watcher). Raises ValueError when the model cannot serve the configured scene."""
        self.models.serve(model, layout)
        self._apply(layout=layout)

    def request_stop(self, *_: Any) -> None:
        self._stop = True

    def request_reload(self, *_: Any) -> None:
        self._reload = True

    def install_signal_handlers(self) -> None:
        signal.signal(signal.SIGTERM, self.request_stop)
        signal.signal(signal.SIGINT, self.request_stop)
        signal.signal(signal.SIGHUP, self.request_reload)

    # -- the hot path ---------------------------------------------------------------------------------
    def handle_frame(self, frame: Frame) -> None:
        """One frame: the detector, and the decision it returns reported."""
        self.frames_received += 1
        for listener in self.listeners:
            listener.on_frame(frame)
        decision = self.detector.feed(frame)
        if decision is not None:
            self._decided(decision)

    def _decided(self, decision: Decision) -> None:
        if decision.problem is not None:
            self.models.take_out_of_service(decision.model, decision.problem)
        else:
            self.reporter.report(decision)
            self.shadow.offer(decision, self.detector.ring)

    def _stuck(self, model: LoadedModel, reason: str) -> None:
        """A decision that did not stop when ended: its file is quarantined before the process exits."""
        self.models.quarantine_now(model, reason)

    def _frame_failed(self, exc: BaseException) -> None:
        """An exception while handling one frame: counted, logged at most every 10 s, never fatal."""
        if self.health.frame_failed(one_line(exc)):
            log.error("frame handling failed (%d so far; the loop goes on): %s: %s", self.health.frame_errors,
                      type(exc).__name__, one_line(exc))

    # -- between frames -------------------------------------------------------------------------------
    def windows_hold(self, now: float) -> bool:
        """Whether open windows still hold back a model swap or a reload that wants in: it waits for
        their decisions, but at most ``HOLD_LIMIT_S``; then the open windows are dropped (one warning
        line), so a trigger that fires all the time cannot keep a new model or config out for ever."""
        if not self.detector.window_open:
            self._held_since = None
            return False
        if self._held_since is None:
            self._held_since = now
        if now - self._held_since < max(HOLD_LIMIT_S, 2 * self.detector.window_s):  # a slow stream's windows end
            return True
        log.warning("a model swap or reload waited %g s for windows that kept opening; %d open window(s) "
                    "dropped undecided to let it in (the trigger fires all the time: see [trigger] "
                    "refractory_s and rearm_quiet_s)", now - self._held_since, self.detector.windows.clear())
        self._held_since = None
        return False

    def _housekeeping(self, now: float) -> None:
        self.notifier.watchdog(now)
        self._swap_and_report(now)
        self.link.link_held()

    def take_pending_model(self, now: float) -> None:
        """Swap in the watcher's validated model, not between a trigger and its window's end
        (``windows_hold``: at most ``HOLD_LIMIT_S``)."""
        if self.models.pending and not self.windows_hold(now):
            self.models.take_pending()

    def _swap_and_report(self, now: float) -> None:
        """Take a pending model and write the health file when due (the loop and a slow connect)."""
        self.take_pending_model(now)
        if now >= self._next_health:
            self._next_health = now + HEALTH_PERIOD_S
            self.write_health(now)

    def _counters(self) -> dict[str, int]:
        """The daemon's own counts: frames handled, sink failures and events refused as invalid JSON, control
        datagrams ignored (not a known message, or from a sender not heard)."""
        if self.control is not None:
            self._control_ignored = self.control.garbage + self.control.refused
        return {"frames_received": self.frames_received, "sink_errors": self.sinks.errors,
                "events_invalid": self.sinks.invalid, "control_ignored": self._control_ignored}

    def write_health(self, now: float | None = None) -> None:
        h = self.health
        h.update_rate(now)
        self.link.update_health(time.monotonic() if now is None else now, HEALTH_PERIOD_S)
        h.hold("sinks", self.sinks.problem)
        h.hold("capture", self.capture.writer.problem if self.capture is not None else None)
        snapshot = h.snapshot()
        self.notifier.status(h.status_line(snapshot))
        if self.status_file is not None:
            self.status_file.write(snapshot)
        self.sinks.health(snapshot)

    def _sinks(self, cfg: Config) -> SinkSet:
        side = DaemonSide(self.robot, self.detector, str(cfg.device.url))
        return SinkSet.from_config(cfg.sinks, self.stream, ros2=cfg.ros2, side=side, instance=self.health.instance)

    def _announce(self, announcement: ModelAnnouncement) -> None:
        self.sinks.emit(announcement)

    def _apply(self, model: Any = _KEEP, layout: SensorLayout | None = None, cfg: Config | None = None,
               lost: bool = False) -> None:
        """The one place the detector changes: the model the slot chose (or None), the layout of a device
        that began to stream (the history is new), the settings of a reloaded config, a stream that broke
        off (``lost``: its history ends). Between frames only."""
        if model is not _KEEP:
            self.detector.swap(model)
        if layout is not None:
            self.detector.fit(layout)
        if lost:
            self.detector.restart()
        if cfg is not None:
            self.detector.configure(cfg.scene, cfg.trigger, cfg.continuous, cfg.control)

    def _connect(self) -> None:
        """A connection attempt; a device that began to stream is fitted (a model that does not fit its
        layout stops serving). During a slow open the link asks ``_connecting`` between its reads."""
        if self.link.connect(self._connecting) is Linked.STREAMING:
            self._stream_began(self.link.layout)

    def _stream_began(self, layout: SensorLayout) -> None:
        self.models.fit_layout(layout)
        self._apply(layout=layout)

    def _link_lost(self) -> None:
        """The link failed: no real-time priority until frames flow again, and the stream's history ends
        now, not at the reconnect (which restarts it anyway): its open windows never get their last
        frames, and held a model dropped or a reload sent during the outage back (``windows_hold``)
        until the device was back, up to ``HOLD_LIMIT_S``; a rollback in that time never served."""
        self.hot_thread.lower()
        self._apply(lost=True)

    def _connecting(self) -> bool:
        """Whether to cancel a slow open (SIGTERM); meanwhile the health file is written and a model dropped
        meanwhile serves at once."""
        self._swap_and_report(time.monotonic())
        return self._stop

    def _hot_thread_raise(self) -> None:
        """The config's ``realtime_priority`` for this (the hot) thread, once the link delivers a valid
        frame; one log line per setting says what came of it (runtime.realtime)."""
        line = self.hot_thread.raise_(self.cfg.realtime_priority)
        if line:
            log.info("%s", line)  # normal scheduling works, only with longer tails under load: not a warning

    # -- control socket ---------------------------------------------------------------------------
    def start_control(self) -> None:
        """Bind ``[control] socket`` if configured; OSError (one line) when it cannot: a daemon deaf to the
        robot's ``grasp open`` must not run as if all were well, so ``handover run`` exits 2."""
        if self.control is None:
            self.control = self._control_for(self.cfg)

    def _control_for(self, cfg) -> ControlSocket | None:
        """The control socket ``cfg`` names: the running one when the address is unchanged, else a new one
        bound while the running one still holds its name (a process looping on bind never gets it between)."""
        if self.control is not None and self.control.address == cfg.control.socket:
            return self.control
        if not cfg.control.socket:
            return None
        return ControlSocket(cfg.control.socket, self.robot.set_grasp, self.robot.set_arm_moving,
                             self.robot.outcome).start()

    # -- field capture ------------------------------------------------------------------------------
    def start_capture(self) -> None:
        """Start field capture if ``[capture] folder`` is set; CaptureError (one line) for a folder another
        user owns or may write to: ``handover run`` exits 2."""
        if self.capture is None:
            self._set_capture(self._capture_for(self.cfg))

    def _capture_for(self, cfg) -> FieldCapture | None:
        """The capture ``cfg`` asks for: the running one when its section is unchanged, else a new one started."""
        if self.capture is not None and cfg.capture == self.cfg.capture:
            return self.capture
        if not cfg.capture.folder:
            return None
        writer = CaptureWriter(cfg.capture.folder, cfg.capture.max_mb).start()
        return FieldCapture(writer, self.detector, self.health.instance, cfg.capture.idle_every_s)

    def _set_capture(self, capture: FieldCapture | None) -> None:
        """Between frames: the listener replaced (the old writer writes what it holds, then ends)."""
        old = self.capture
        if capture is old:
            return
        if old is not None:
            self.listeners.remove(old)
            old.close()
        if capture is not None:
            self.listeners.append(capture)
        self.capture = self.robot.capture = capture

    def stop_control(self) -> None:
        if self.control is not None:
            self.control.stop()
            self.control = None

    # -- SIGHUP -------------------------------------------------------------------------------------
    def reload(self) -> None:
        """Reload the config file and apply what changed; an invalid file keeps the running config.
        Called by the loop only between windows (never between a trigger and its window's end)."""
        self._reload = False
        source = self.cfg.source
        if not source:
            log.warning("SIGHUP: no config file to reload")
            return
        self.notifier.reloading()
        control = None
        try:
            new = load_config(source)
            control = self._control_for(new)
            capture = self._capture_for(new)
        except Exception as exc:  # a ConfigError, a socket, or any bug in a check: never fatal to a running daemon
            if control not in (None, self.control):
                control.stop()
            known = isinstance(exc, (ConfigError, OSError, CaptureError))
            return self._refuse_reload(one_line(exc) if known else f"{type(exc).__name__}: {one_line(exc)}")
        if self.locks is not None and (held := self.locks.retarget(new)):
            if control not in (None, self.control):
                control.stop()
            if capture not in (None, self.capture):
                capture.writer.stop()
            return self._refuse_reload(held)
        old, self.cfg = self.cfg, new
        set_log_level(new.log_level)
        for warning in new.warnings:
            log.warning("%s", warning)
        self.sinks.close()
        self.health.instance = instance_of(new)
        self.reporter.sinks = self._sinks(new)
        if control is not self.control:
            self.stop_control()
            self.control = control
        self._set_capture(capture)
        if new.realtime_priority != old.realtime_priority and self.hot_thread.applied:
            self.hot_thread.lower()  # taken at once while streaming, else with the next frame
            self._hot_thread_raise()
        if new.health_file != old.health_file:
            self.status_file = StatusFile(new.health_file) if new.health_file else None
        self.link.retarget(new.device)
        self.link.scene = new.scene.pads
        self.models.refit(old, new)
        self.shadow.refit(new)
        self._apply(cfg=new)
        self.health.resolve("config")
        log.info("configuration reloaded from %s (%s)", source, changed_sections(old, new))
        self.notifier.ready(self.health.status_line())

    def _refuse_reload(self, reason: str) -> None:
        log.error("SIGHUP: %s; keeping the running configuration", reason)
        self.health.report_error(f"reload refused: {reason}", "config")
        self.notifier.ready(self.health.status_line())

    # -- main loop ------------------------------------------------------------------------------
    def run(self) -> int:
        """Serve until SIGTERM / request_stop(); returns 0, or 2 when the device URL can never
        work (``self.fatal`` says why)."""
        set_log_level(self.cfg.log_level)
        for warning in self.cfg.warnings:
            log.warning("%s", warning)
        self.start_control()  # handover run binds it first (refused: exit 2); a bare run raises here, before starting
        self.start_capture()
        self.models.start()
        self.shadow.start()
        self.guard.start()
        settle_heap()
        self.notifier.ready(self.health.status_line())
        log.info("handover daemon ready (device %s, scene %s, mode %s)", self.cfg.device.url,
                 self.cfg.scene.pads, self.cfg.scene.mode)
        link = self.link
        read = RehearsedReads(link.read, self.detector, READ_TIMEOUT_S)
        try:
            while not self._stop and link.fatal is None:
                if self._reload and not self.windows_hold(time.monotonic()):  # not inside a window
                    self.reload()
                now = time.monotonic()
                self._housekeeping(now)
                if not link.connected:
                    if link.due(now):
                        self._connect()
                    else:
                        time.sleep(min(READ_TIMEOUT_S, link.wait_s(now)))
                    continue
                frame = read()
                if frame is None:
                    if not link.connected:
                        self._link_lost()
                    continue
                if not self.hot_thread.applied:
                    self._hot_thread_raise()
                try:
                    self.handle_frame(frame)
                except Exception as exc:  # never let one frame end the service
                    self._frame_failed(exc)
        finally:
            self.shutdown()
            self.hot_thread.lower()
        return 2 if self.fatal else 0

    def shutdown(self) -> None:
        """STOPPING=1, stop the watcher, close the device, flush the sinks, final health."""
        self.notifier.stopping()
        self.guard.stop()
        self.models.stop(timeout=0.5)
        self.shadow.stop(timeout=0.1)  # a candidate still warming up must not hold SIGTERM past 1 s (daemon thread)
        self.stop_control()
        if self.capture is not None:  # its counts stay in the final health view
            self.capture.close()
        self.link.shutdown(SHUTDOWN_STOP_S)
        if self.fatal:
            self.health.report_error(self.fatal, "device")
        self.write_health()
        self.sinks.close()
        log.info("stopped: %d frames, %d events, %d missed deadlines", self.frames_received,
                 self.reporter.events, self.reporter.missed_deadlines)
