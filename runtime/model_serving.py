"""Which model serves, and the ring and trigger fitted to it (mixed into ``runtime.daemon.Daemon``).

A model reaches the hot path in one reference assignment between two windows: the watcher
thread loads, validates and warms up model files; ``_use_model`` swaps one in and rebuilds the
ring and trigger for it; a model that breaks the output contract at run time is taken out of
service and the one it replaced serves again. Nothing here runs per frame.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from firmware_io.layout import SensorLayout
from runtime.arm_motion import ArmMotion, arm_frames
from runtime.decision import ContinuousDecision
from runtime.health import Health
from runtime.model_watch import ModelWatcher, Rejection
from runtime.quarantine import QuarantineStore
from runtime.ring import RingBuffer
from runtime.scene import scene_pads, scene_problem
from runtime.sinks import ModelAnnouncement, SinkSet
from runtime.trigger import ContinuousTrigger, ThresholdTrigger
from runtime.trigger_settings import TriggerSettings, build_trigger, resolve_trigger

log = logging.getLogger("handover.daemon")

DEFAULT_RATE_HZ = 32.0


class ModelServing:
    """Model swaps and the hot path's state fitted to the model, scene and layout.

    Expects ``cfg``, ``health``, ``sinks``, ``quarantine``, ``layout``, ``grasp_closed`` and
    ``_pending`` (the frames whose windows are due) on the instance.
    """

    cfg: Any
    health: Health
    sinks: SinkSet
    quarantine: QuarantineStore
    layout: SensorLayout | None
    grasp_closed: bool | None
    _pending: list[int]
    model: Any
    _fallback: Any
    _announced: Any
    ring: RingBuffer | None
    trigger: Any
    trigger_settings: TriggerSettings | None
    decision: ContinuousDecision | None
    arm: ArmMotion
    watcher: ModelWatcher | None
    period_s: float
    frame_clock: Any  # runtime.frame_rate.FrameClock
    rehearsal: Any  # runtime.rehearsal.Rehearsal
    _trigger_key: tuple | None

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

    def _take_pending_model(self, now: float) -> None:
        """Swap in the watcher's validated model, not between a trigger and its window's end
        (``windows_hold``: at most ``HOLD_LIMIT_S``)."""
        if self.watcher is not None and self.watcher.pending is not None and not self.windows_hold(now):
            model = self.watcher.take()
            if model is not None:
                self._use_model(model)

    def _use_model(self, model: Any) -> None:
        """Swap the serving model (one reference assignment), fit the hot path to it, announce it."""
        old = self.model
        if old is not None and old is not model:
            self._fallback = old
        self.model = model
        self.health.model_id = model.model_id
        self.health.models_loaded += 1
        self.health.resolve("model")
        # the model announced last, also when a reload or a quarantine took it out before this one came
        previous, self._announced = self._announced, model
        self.sinks.emit(ModelAnnouncement.of(model, self.health.models_loaded, previous))
        period_s = 1.0 / float(model.meta.sample_rate_hz or DEFAULT_RATE_HZ)
        same_rate = period_s == self.period_s  # frames kept at another rate would splice two time scales
        self.period_s = period_s
        self.frame_clock.set_model_period(1000.0 * period_s)
        self._build_hot_path(keep_history=same_rate)
        what = "swapped in" if old is not None else "serving"
        log.info("model %s %s (%s, T=%d, classes %s; %s)", model.model_id, what, Path(model.path).name,
                 model.meta.T, ",".join(model.meta.classes), self._windows_by(model))

    def _windows_by(self, model: Any) -> str:
        """What starts a window with ``model`` (settings come from the config, else the model: a swap may
        change the trigger, and the operator should read that)."""
        if self.cfg.scene.mode == "continuous":
            return "continuous mode: a decision every frame"
        return f"{resolve_trigger(self.cfg.trigger, model.meta.trigger).name} trigger"

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
        mode = self.cfg.scene.mode
        fullscale = float(meta.fullscale) if meta else self.layout.fullscale
        inputs = (settings, tuple(self.layout.pad_sizes(pads)), fullscale, T, 1.0 / self.period_s,
                  tuple(self.layout.pad_fingers(pads)))  # build_trigger's arguments
        key = (mode, self.cfg.continuous if mode == "continuous" else None, cols.tobytes(),
               meta.classes if meta else None, meta.dormant_class if meta else None, inputs)
        # the same trigger and report rule (a SIGHUP that changed other sections, a model of the same kind
        # swapped in) keep their state, e.g. the onset trigger's settled grasp
        if not (keep_history and self.trigger is not None and key == self._trigger_key):
            self._new_trigger(inputs, meta, keep_history)
        self._trigger_key = key
        self.arm.configure(*arm_frames(1.0 / self.period_s, self.cfg.control.arm_settle_s,
                                       self.cfg.control.arm_max_move_s))
        self._pending.clear()
        self.rehearsal.cancel()  # a rehearsal of the old ring or model is not worth running

    def _new_trigger(self, inputs: tuple, meta: Any, keep_history: bool) -> None:
        """A trigger (and continuous mode's report rule) for ``build_trigger``'s ``inputs``; a threshold
        trigger takes over the old one's arming, an onset trigger the robot's closed grasp."""
        old = self.trigger
        self.decision = None
        if self.cfg.scene.mode == "continuous":
            self.trigger = ContinuousTrigger(inputs[3])
            if meta is not None and meta.dormant_class in meta.classes:
                cc = self.cfg.continuous
                self.decision = ContinuousDecision(
                    len(meta.classes), list(meta.classes).index(meta.dormant_class), confirm_frames=cc.confirm_frames,
                    min_margin=cc.min_margin, rearm_frames=cc.rearm_frames,
                    gap_frames=cc.gap_frames, vote=cc.vote)
            return
        self.trigger = build_trigger(*inputs)
        if isinstance(old, ThresholdTrigger) and isinstance(self.trigger, ThresholdTrigger) and keep_history:
            self.trigger.armed, self.trigger.last_trigger, self.trigger.quiet = old.armed, old.last_trigger, old.quiet
        elif keep_history and self.grasp_closed and hasattr(self.trigger, "set_grasp"):
            self.trigger.set_grasp(True)  # a new trigger on the same settled grasp

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
