"""The detection daemon's main loop: frames -> ring -> trigger -> inference -> sinks.

One thread does the hot path. Per frame: copy the scene's columns into the ring, one max for
the trigger; only when a window's last frame has arrived does the model run, at once, and the
time from that frame's arrival (``Frame.received``) to the decision is recorded. A decision
later than one sample period is a missed deadline.

Everything slow happens elsewhere or between frames: model files are validated and warmed
up by the watcher thread and swapped in by one reference assignment between two windows;
the health file is written about once a second; the device is reopened with backoff after
an unplug or a stall; SIGTERM ends the loop within a read timeout (0.1 s); SIGHUP reloads
the config and keeps the old one if the new one is invalid.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import numpy as np

from firmware_io.layout import SensorLayout
from runtime.config import Config, ConfigError, load_config
from runtime.control import ControlSocket, GraspControl
from runtime.decision import ContinuousDecision
from runtime.frame_rate import FrameClock
from runtime.health import Health, StatusFile
from runtime.listeners import DecisionTimings, FrameListener
from runtime.model_watch import ModelWatcher, Rejection
from runtime.output_check import output_problem
from runtime.quarantine import QuarantineStore, store_path
from runtime.ring import RingBuffer
from runtime.scene import events_problem, scene_pads, scene_problem
from runtime.sdnotify import Notifier
from runtime.sinks import Event, ModelAnnouncement, SinkSet
from runtime.trigger import ContinuousTrigger, ThresholdTrigger
from runtime.trigger_settings import TriggerSettings, build_trigger, resolve_trigger

__all__ = ["Daemon", "events_problem", "scene_problem"]  # the last two are re-exported for run --check

log = logging.getLogger("handover.daemon")

READ_TIMEOUT_S = 0.1
"""Longest the loop blocks on the device: bounds the reaction to SIGTERM and the watchdog."""
HEALTH_PERIOD_S = 1.0
SHUTDOWN_STOP_S = 0.3
"""Longest the stop handshake may take at shutdown (SIGTERM must end the process within 1 s)."""
DEFAULT_RATE_HZ = 32.0
CONNECT_BOUND_S = 30.0
"""Longest one connection attempt may take while the watchdog is still fed: the client's own
deadlines end an open within ~15 s (open 10 s, start 3 s), so an attempt still running after this
is a hang, and systemd's watchdog is left to catch it."""


class Daemon(GraspControl):
    """The long-running service. ``run()`` returns the exit code."""

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
        self.client_factory = client_factory or _default_client
        self.on_event = on_event
        self.health = Health()
        self.status_file: StatusFile | None = StatusFile(cfg.health_file) if cfg.health_file else None
        self.latest_frame: Any = None
        """The newest frame (the ROS 2 sink's pad images read it from their own thread)."""
        self.grasp_request: tuple[bool, str] | None = None
        """The latest ``set_grasp`` call: (closed, source)."""
        self.sinks = SinkSet.from_config(cfg.sinks, stream, ros2=cfg.ros2, daemon=self)
        self.model: Any = None
        self._fallback: Any = None
        """The model the last swap replaced: it serves again if the new one is taken out of service."""
        self.quarantine = QuarantineStore(store_path(cfg.model.quarantine_file, cfg.health_file))
        self.layout: SensorLayout | None = None
        self.client: Any = None
        self.connected = False
        self.ring: RingBuffer | None = None
        self.trigger: Any = None
        """ThresholdTrigger, OnsetTrigger (runtime/onset.py) or ContinuousTrigger."""
        self.trigger_settings: TriggerSettings | None = None
        self._grasp_requests: deque[tuple[bool, str]] = deque(maxlen=64)
        self.grasp_closed: bool | None = None
        """The robot's last word on its grasp (``set_grasp``), None before any."""
        self.control: ControlSocket | None = None
        self.decision: ContinuousDecision | None = None
        """Continuous mode's report rule (confirm, margin, one report per interaction)."""
        self.watcher: ModelWatcher | None = None
        self._stop = False
        self._reload = False
        self.fatal: str | None = None
        """Why the daemon gave up (a device URL that can never open, a missing package), or None."""
        self._pending: list[int] = []
        self._backoff = cfg.device.reconnect_min_s
        self._next_connect = 0.0
        self._last_frame_t = 0.0
        self._next_health = 0.0
        self._connect_started: float | None = None
        self.connect_bound_s = CONNECT_BOUND_S
        self._hang_logged = False
        self.period_s = 1.0 / DEFAULT_RATE_HZ
        self.frame_clock = FrameClock(1000.0 * self.period_s, self.health, on_restart=self._restart_stream)
        """Feeds the model at its trained period: decimates faster streams, warns on slower ones."""
        self.listeners: list[FrameListener] = []
        """Called with every frame handled and every decision's stage timings (runtime.listeners);
        benchmarks and tests observe the real hot path through them. Empty: one list check per frame."""

    # -- control --------------------------------------------------------------------------------
    def request_stop(self, *_: Any) -> None:
        self._stop = True

    def request_reload(self, *_: Any) -> None:
        self._reload = True

    def install_signal_handlers(self) -> None:
        signal.signal(signal.SIGTERM, self.request_stop)
        signal.signal(signal.SIGINT, self.request_stop)
        signal.signal(signal.SIGHUP, self.request_reload)

    # -- models ---------------------------------------------------------------------------------
    def serve(self, model: Any, layout: SensorLayout) -> None:
        """Serve ``model`` for a device with ``layout``, fed by the caller through ``handle_frame``.

        For replays, benchmarks and embedding: no device, no model watcher. Raises ValueError
        when the model cannot serve the configured scene (the watcher's check, one line).
        """
        problem = scene_problem(model, self.cfg, layout)
        if problem:
            raise ValueError(f"model {model.model_id}: {problem}")
        if layout != self.layout:
            self.layout = layout
            self.ring = None
        self._use_model(model)

    def _load(self, path: Path) -> Any:
        from runtime.model import load_model

        ox = self.cfg.onnxruntime
        return load_model(path, max_bytes=self.cfg.model.max_bytes, intra_op_threads=ox.intra_op_threads,
                          allow_spinning=ox.allow_spinning, warm_up=False)

    def _rejected(self, rejection: Rejection) -> None:
        self.health.models_rejected += 1
        self.health.report_error(f"model {rejection.path.name} rejected: {rejection.reason}", "model")

    def _start_watcher(self) -> None:
        if self.watcher is not None:
            self.watcher.stop()
        self.watcher = ModelWatcher(
            self.cfg.model.folder,
            loader=self._load,
            check=lambda m: scene_problem(m, self.cfg, self.layout),
            poll_interval=self.cfg.model.poll_interval_s,
            on_reject=self._rejected,
            decision_budget=self.cfg.model.decision_budget,
            quarantine=self.quarantine,
        )
        model = self.watcher.poll(require_stable=False)
        self.watcher.take()
        if model is not None:
            self._use_model(model)
        elif self.model is None:
            log.warning("no valid model in %s yet; waiting for one (frames are read, nothing is classified)",
                        self.cfg.model.folder)
        self.watcher.start()

    def _use_model(self, model: Any) -> None:
        """Swap the serving model (one reference assignment), fit the hot path to it, announce it."""
        old = self.model
        if old is not None and old is not model:
            self._fallback = old
        self.model = model
        self.health.model_id = model.model_id
        self.health.models_loaded += 1
        self.health.resolve("model")
        self.sinks.emit(ModelAnnouncement.of(model, self.health.models_loaded, old))
        self.period_s = 1.0 / float(model.meta.sample_rate_hz or DEFAULT_RATE_HZ)
        self.frame_clock.set_model_period(1000.0 * self.period_s)
        self._build_hot_path(keep_history=True)
        what = "swapped in" if old is not None else "serving"
        log.info("model %s %s (%s, T=%d, classes %s)", model.model_id, what, Path(model.path).name,
                 model.meta.T, ",".join(model.meta.classes))

    def _build_hot_path(self, keep_history: bool) -> None:
        """Ring and trigger for the current layout, scene and model (not on the per-frame path)."""
        if self.layout is None:
            return
        pads = scene_pads(self.cfg, self.model, self.layout)
        cols = self.layout.columns(pads)
        meta = self.model.meta if self.model is not None else None
        T = int(meta.T) if meta else 15
        settings = resolve_trigger(self.cfg.trigger, meta.trigger if meta else None)
        self.trigger_settings = settings
        capacity = max(64, 2 * (T + settings.pre_frames))
        if self.ring is None or not keep_history or self.ring.columns.size != cols.size or not np.array_equal(
            self.ring.columns, cols
        ):
            self.ring = RingBuffer(cols, capacity)
        elif self.ring.capacity < capacity:
            self.ring = self.ring.resized(capacity)
        old = self.trigger
        self.decision = None
        if self.cfg.scene.mode == "continuous":
            self.trigger = ContinuousTrigger(T)
            if meta is not None and meta.dormant_class in meta.classes:
                cc = self.cfg.continuous
                self.decision = ContinuousDecision(
                    len(meta.classes), list(meta.classes).index(meta.dormant_class), confirm_frames=cc.confirm_frames,
                    min_margin=cc.min_margin, rearm_frames=cc.rearm_frames)
        else:
            fullscale = float(meta.fullscale) if meta else self.layout.fullscale
            pad_sizes = self.layout.pad_sizes(pads)
            self.trigger = build_trigger(settings, pad_sizes, fullscale, T, 1.0 / self.period_s)
            if isinstance(old, ThresholdTrigger) and isinstance(self.trigger, ThresholdTrigger) and keep_history:
                self.trigger.armed, self.trigger.last_trigger, self.trigger.quiet = old.armed, old.last_trigger, old.quiet
            elif keep_history and self.grasp_closed and hasattr(self.trigger, "set_grasp"):
                self.trigger.set_grasp(True)  # a new trigger on the same settled grasp
        self._pending.clear()

    # -- device ---------------------------------------------------------------------------------
    def _still_connecting(self) -> bool:
        """The client's cancel predicate while it opens a device (seconds when the device is
        silent): answers SIGTERM within a read slice, keeps the health file current, and feeds
        the watchdog only while the attempt is within ``connect_bound_s`` (a hang past it is
        left to systemd's watchdog)."""
        now = time.monotonic()
        started = self._connect_started
        if started is None or now - started < self.connect_bound_s:
            self.notifier.watchdog(now)
        elif not self._hang_logged:
            self._hang_logged = True
            self.health.report_error(f"{self.cfg.device.url}: connecting has not completed in "
                                     f"{self.connect_bound_s:g} s", "device")
            log.error("device %s: connecting has not completed in %g s; no longer feeding the watchdog "
                      "(systemd restarts the service)", self.cfg.device.url, self.connect_bound_s)
        self._swap_and_report(now)  # a model dropped while a slow connect runs serves at once
        return self._stop

    def _connect(self) -> None:
        from firmware_io.client import Cancelled

        h = self.health
        url = self.cfg.device.url
        self._connect_started, self._hang_logged = time.monotonic(), False
        if h.device_state in ("starting", "stopped"):
            h.device_state = "connecting"
        try:
            if self.client is None:
                self.client = self.client_factory(url)
            layout = self.client.open(should_stop=self._still_connecting)
            self.client.start(should_stop=self._still_connecting)
        except Cancelled:
            self._connect_started = None
            self._close_client()
            return
        except Exception as exc:  # unplugged, refused, wrong device: report and retry, never die
            fatal = _fatal_device_error(url, exc)
            if fatal:
                self.fatal = fatal
                self._stop = True  # run() returns 2; the caller prints self.fatal (one line)
                self._close_client()
                return
            self._connect_started = None
            h.device_state = "disconnected"
            reason = _one_line(exc).removeprefix(f"{url}: ")
            h.report_error(f"{url}: {reason}", "device")
            log.warning("device %s: %s; retrying in %.1f s", url, reason, self._backoff)
            self._schedule_reconnect()
            self._close_client()
            return
        self._connect_started = None
        self.connected = True
        first = self.layout is None
        if self.layout != layout:
            self.layout = layout
            if self.model is not None:
                problem = scene_problem(self.model, self.cfg, layout)
                if problem:
                    log.error("model %s does not fit the device: %s; waiting for another model",
                              self.model.model_id, problem)
                    self.model = None
                    self.health.model_id = None
            self._build_hot_path(keep_history=False)
        else:
            self._restart_stream()
        self.frame_clock.reset()
        self._last_frame_t = time.monotonic()
        h.device_state = "streaming"
        h.resolve("device")
        log.info("device %s %s (%d taxels, scene %s)", url, "connected" if first else "reconnected",
                 layout.n_taxels, self.cfg.scene.pads)

    def _restart_stream(self) -> None:
        """The stream is not continuous (a reconnect, a long gap in device time): forget its history."""
        if self.ring is not None:
            self.ring.reset()
            self.trigger.reset()
        if self.decision is not None:
            self.decision.reset()
        self._pending.clear()

    def _schedule_reconnect(self) -> None:
        self._next_connect = time.monotonic() + self._backoff
        self._backoff = min(self.cfg.device.reconnect_max_s, max(self._backoff * 2, 0.05))

    def _fault(self, reason: str) -> None:
        reason = reason.removeprefix(f"{self.cfg.device.url}: ")
        h = self.health
        h.device_faults += 1
        h.reconnects += 1
        h.device_state = "reconnecting"
        h.report_error(f"{self.cfg.device.url}: {reason}", "device")
        log.warning("device %s: %s; reconnecting", self.cfg.device.url, reason)
        self._close_client()
        self._schedule_reconnect()

    def _close_client(self, stop_timeout: float | None = None) -> None:
        self.connected = False
        if self.client is not None:
            with contextlib.suppress(Exception):
                if stop_timeout is None:
                    self.client.close()
                else:
                    self.client.close(stop_timeout=stop_timeout)

    def _absorb_client_stats(self) -> None:
        """The client's error counters (cumulative over reconnects of the same client)."""
        stats = getattr(self.client, "stats", None)
        if not isinstance(stats, dict):
            return
        self.health.crc_errors = int(stats.get("crc_errors", 0))
        self.health.protocol_errors = int(stats.get("bad_headers", 0)) + int(stats.get("decode_errors", 0))
        self.health.frames_implausible = int(stats.get("frames_implausible", 0))
        self.health.frames_stale = int(stats.get("frames_stale", 0))

    # -- the hot path -----------------------------------------------------------------------------
    def handle_frame(self, frame: Any) -> None:
        """One frame: ring, trigger, and inference if this frame ends a window."""
        self.health.frames_received += 1
        number = self.frame_clock.admit(frame.number, frame.timestamp_ms)  # the model's frame count, -1: between
        if number < 0:
            return
        if self.listeners:
            for listener in self.listeners:
                listener.on_frame(frame)
        self.latest_frame = frame
        ring = self.ring
        ring.push(frame.values, number)
        if self._grasp_requests:
            self._apply_grasp()
        due = self.trigger.update(ring.latest(), number)
        if self.model is None:
            return
        pending = self._pending
        if due >= 0:
            pending.append(due)
        if pending and number >= pending[0]:
            due = pending.pop(0)
            if number == due and ring.count >= self.model.meta.T:
                self._classify(frame)

    def _classify(self, frame: Any) -> None:
        """Run the model on the window ending at ``frame``, check, report; each stage stamped."""
        clock = time.perf_counter
        model = self.model
        meta = model.meta
        started = clock()
        window = self.ring.window(meta.T)  # a float32 [1, T, C] view of the ring: no copy
        windowed = clock()
        try:
            labels, scores = model.run_trusted(window)
        except Exception as exc:  # a graph that fails on real frames only
            self._take_out_of_service(model, f"inference failed on frames {frame.number - meta.T + 1}.."
                                             f"{frame.number}: {_one_line(exc)}")
            return
        decided = clock()
        problem = output_problem(labels, scores, meta.n_classes)
        if problem:
            self._take_out_of_service(model, f"{problem} (frames {frame.number - meta.T + 1}..{frame.number})")
            return
        stamps = DecisionTimings(frame.received, started, windowed, decided, clock())
        latency_us = (decided - frame.received) * 1e6
        h = self.health
        h.decisions += 1
        h.record_latency(latency_us)
        missed = latency_us > self.period_s * 1e6
        if missed:
            h.missed_deadlines += 1
        index = int(labels[0])
        if self.decision is not None:  # continuous mode: one report per confirmed interaction
            index = self.decision.update(index, scores[0])
        cls = meta.classes[index] if index >= 0 else None
        if cls is not None and cls in self.cfg.scene.events:
            event = Event(time.time(), cls, dict(zip(meta.classes, scores[0].tolist(), strict=True)), latency_us,
                          model.model_id, self.frame_clock.window_first(frame.number, meta.T), frame.number,
                          int(frame.timestamp_ms), missed)
            stamps.built = clock()
            encoded = self.sinks.encode(event)
            stamps.serialised = clock()
            h.events += 1
            if encoded is not None:
                self.sinks.send(*encoded)
            stamps.sent = clock()
            if self.on_event is not None:
                self.on_event(event)
        if self.listeners:
            for listener in self.listeners:
                listener.on_decision(frame, stamps)

    def _take_out_of_service(self, model: Any, reason: str) -> None:
        """A model broke the output contract at run time: one line, never load this file version
        again (also after a restart), and serve the model it replaced, or none."""
        h = self.health
        h.models_quarantined += 1
        (self.watcher or self.quarantine).quarantine_file(Path(model.path), reason)
        fallback, self._fallback = self._fallback, None
        if fallback is not None and scene_problem(fallback, self.cfg, self.layout):
            fallback = None
        h.report_error(f"model {Path(model.path).name} taken out of service: {reason}", "quarantine")
        what = "no model serves until the watcher finds the next newest valid file or a new one is dropped"
        if fallback is not None:
            what = f"model {fallback.model_id} ({Path(fallback.path).name}) serves again"
        log.error("model %s (%s) taken out of service: %s; it is not loaded again until the file changes; %s",
                  model.model_id, Path(model.path).name, reason, what)
        self.model, h.model_id = None, None
        if fallback is not None:
            self._use_model(fallback)  # announced to the sinks like any model that starts serving
        else:
            self._pending.clear()
            if self.watcher is not None:
                self.watcher.reconsider_older()

    def _frame_failed(self, exc: BaseException) -> None:
        """An exception while handling one frame: counted, logged at most every 10 s, never fatal."""
        if self.health.frame_failed(_one_line(exc)):
            log.error("frame handling failed (%d so far; the loop goes on): %s: %s", self.health.frame_errors,
                      type(exc).__name__, _one_line(exc))

    # -- housekeeping ---------------------------------------------------------------------------
    def _housekeeping(self, now: float) -> None:
        self.notifier.watchdog(now)
        self._swap_and_report(now)

    def _swap_and_report(self, now: float) -> None:
        """Take a pending model and write the health file when due (the loop and a slow connect)."""
        self._take_pending_model()
        if now >= self._next_health:
            self._next_health = now + HEALTH_PERIOD_S
            self.write_health(now)

    def _take_pending_model(self) -> None:
        """Swap in the watcher's validated model, never between a trigger and its window's end."""
        if self.watcher is not None and self.watcher.pending is not None and not self._pending:
            model = self.watcher.take()
            if model is not None:
                self._use_model(model)

    def write_health(self, now: float | None = None) -> None:
        h = self.health
        h.update_rate(now)
        self._absorb_client_stats()
        h.sink_errors = self.sinks.errors
        h.events_invalid = self.sinks.invalid
        self.notifier.status(h.status_line())
        snapshot = h.snapshot()
        if self.status_file is not None:
            self.status_file.write(snapshot)
        self.sinks.health(snapshot)

    def _do_reload(self) -> None:
        self._reload = False
        source = self.cfg.source
        if not source:
            log.warning("SIGHUP: no config file to reload")
            return
        self.notifier.reloading()
        try:
            new = load_config(source)
        except ConfigError as exc:
            log.error("SIGHUP: %s; keeping the running configuration", exc)
            self.health.report_error(f"reload refused: {exc}", "config")
            self.notifier.ready(self.health.status_line())
            return
        old, self.cfg = self.cfg, new
        _set_log_level(new.log_level)
        for warning in new.warnings:
            log.warning("%s", warning)
        self.sinks.close()
        self.sinks = SinkSet.from_config(new.sinks, self.stream, ros2=new.ros2, daemon=self)
        if new.control != old.control or self.control is None:  # also retries one that could not bind
            self.stop_control()
            self.start_control()
        if new.health_file != old.health_file:
            self.status_file = StatusFile(new.health_file) if new.health_file else None
        if new.device.url != old.device.url:
            self._close_client()
            self.client = None
            self.layout = None
            self._next_connect = 0.0
        if new.scene != old.scene or new.model != old.model or new.onnxruntime != old.onnxruntime:
            if self.model is not None and scene_problem(self.model, new, self.layout):
                log.warning("the model in use does not fit the new scene; waiting for one that does")
                self.model = None
                self.health.model_id = None
            if new.model != old.model or new.onnxruntime != old.onnxruntime:
                self._start_watcher()
            elif self.watcher is not None:  # a file rejected under the old scene may fit the new one
                self.watcher.rescan(keep_current=self.model is not None)
        self._build_hot_path(keep_history=new.scene == old.scene)
        self.health.resolve("config")
        log.info("configuration reloaded from %s", source)
        self.notifier.ready(self.health.status_line())

    # -- main loop ------------------------------------------------------------------------------
    def run(self) -> int:
        """Serve until SIGTERM / request_stop(); returns 0, or 2 when the device URL can never
        work (``self.fatal`` says why)."""
        _set_log_level(self.cfg.log_level)
        for warning in self.cfg.warnings:
            log.warning("%s", warning)
        self._start_watcher()
        self.start_control()
        self.notifier.ready(self.health.status_line())
        log.info("handover daemon ready (device %s, scene %s, mode %s)", self.cfg.device.url,
                 self.cfg.scene.pads, self.cfg.scene.mode)
        try:
            while not self._stop:
                if self._reload and not self._pending:  # never between a trigger and its window's end
                    self._do_reload()
                now = time.monotonic()
                self._housekeeping(now)
                if not self.connected:
                    if now >= self._next_connect:
                        self._connect()
                    else:
                        time.sleep(min(READ_TIMEOUT_S, self._next_connect - now))
                    continue
                try:
                    frame = self.client.read_frame(timeout=READ_TIMEOUT_S)
                except Exception as exc:  # unplug, closed link, end of a replay: reconnect
                    self._fault(_one_line(exc))
                    continue
                if frame is None:
                    if time.monotonic() - self._last_frame_t > self.cfg.device.stall_timeout_s:
                        self.health.stalls += 1
                        self._fault(f"no frame for {self.cfg.device.stall_timeout_s:g} s (stall)")
                    continue
                self._last_frame_t = time.monotonic()
                self._backoff = self.cfg.device.reconnect_min_s
                try:
                    self.handle_frame(frame)
                except Exception as exc:  # never let one frame end the service
                    self._frame_failed(exc)
        finally:
            self.shutdown()
        return 2 if self.fatal else 0

    def shutdown(self) -> None:
        """STOPPING=1, stop the watcher, close the device, flush the sinks, final health."""
        self.notifier.stopping()
        if self.watcher is not None:
            self.watcher.stop(timeout=0.5)
        self.stop_control()
        self._close_client(stop_timeout=SHUTDOWN_STOP_S)
        self.health.device_state = "stopped" if not self.fatal else "failed"
        if self.fatal:
            self.health.report_error(self.fatal, "device")
        self.write_health()
        self.sinks.close()
        log.info("stopped: %d frames, %d events, %d missed deadlines", self.health.frames_received,
                 self.health.events, self.health.missed_deadlines)


def _default_client(url: str) -> Any:
    from firmware_io.client import DSAClient

    # The daemon reconnects itself (with backoff, answering SIGTERM and the watchdog meanwhile).
    return DSAClient(url, auto_reconnect=False)


def _fatal_device_error(url: str, exc: BaseException) -> str | None:
    """A device error no retry can cure: the URL itself is wrong, or a package is missing.

    Everything else (unplugged, refused, silent, wrong replies) is retried with backoff."""
    from firmware_io.transports import DeviceUnavailable, MissingDependency, TransportError, validate_url

    if not isinstance(exc, TransportError) or isinstance(exc, DeviceUnavailable):
        return None
    if isinstance(exc, MissingDependency):
        return f"device.url: {_one_line(exc)}"
    try:
        validate_url(url)
    except TransportError as bad:
        return f"device.url: {_one_line(bad)}"
    return None  # e.g. a write timeout: a device condition, retried


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _set_log_level(level: str) -> None:
    logging.getLogger("handover").setLevel(level.upper())
