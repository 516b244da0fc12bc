"""Which model serves: the model folder's watcher with its quarantine, swaps, and the fallback when a
model breaks at run time.

The watcher thread loads, validates and warms up files; ``take_pending`` hands one to the owner's
``serve`` (the daemon swaps it into its detector between two windows); a model that breaks the output
contract is taken out of service and the one it replaced serves again. Nothing here runs per frame.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from firmware_io.layout import SensorLayout
from runtime.config import Config
from runtime.health import Health
from runtime.model import load_model
from runtime.model_change import served, swap_warning, trigger_text
from runtime.model_watch import ModelWatcher, Rejection
from runtime.quarantine import QuarantineStore, store_path
from runtime.scene import scene_problem
from runtime.sinks import ModelAnnouncement
from runtime.trigger_settings import resolve_trigger

if TYPE_CHECKING:
    from runtime.model import LoadedModel

__all__ = ["ModelSlot"]

log = logging.getLogger("handover.daemon")


class ModelSlot:
    """Which model serves: watched for in ``cfg.model.folder``, swapped in, taken out of service.

    ``serve`` receives every change of the serving model (a model, or None) and ``announce`` a
    ``ModelAnnouncement`` for every model that starts serving (the daemon hands it to its sinks)."""

    def __init__(self, cfg: Config, health: Health, serve: Callable[[LoadedModel | None], None],
                 announce: Callable[[ModelAnnouncement], None]) -> None:
        self.cfg = cfg
        """The running config (the model, onnxruntime, scene and trigger sections are read; the owner
        sets a reloaded one with ``refit``)."""
        self.serve_model = serve
        self.health = health
        self.model: LoadedModel | None = None
        """The model that serves now (the one last handed to ``serve``)."""
        self.layout: SensorLayout | None = None
        """The device's layout models are weighed against (``fit_layout``; None until a device streams)."""
        self.announce = announce
        self.quarantine = QuarantineStore(store_path(cfg.model.quarantine_file, cfg.health_file))
        self.watcher: ModelWatcher | None = None
        self._said_rejections: dict = {}
        """The watcher's memory of rejections it logged, kept when a reload replaces the watcher."""
        self._fallback: LoadedModel | None = None
        """The model the last swap replaced: it serves again if the new one is taken out of service."""
        self._announced: LoadedModel | None = None
        """The model of the last announcement: the next one's ``previous_model_id``."""
        self._served: dict | None = None
        """What the model that served last meant to the stream (runtime.model_change.served)."""
        self.loaded = 0
        """Models that started serving (the first and every swap)."""
        self.rejected = 0
        """Model files rejected, once per file version and reason."""
        self.quarantined = 0
        """Models taken out of service at run time (a label out of range, NaN scores, a failed run)."""
        self.trigger: str | None = None
        """The trigger serving now, with its settings (e.g. ``onset (change 0.12, ...)``), or None without a model."""

    def counters(self) -> dict[str, int | str | None]:
        return {"models_loaded": self.loaded, "models_rejected": self.rejected, "models_quarantined": self.quarantined,
                "model_id": self.model.model_id if self.model is not None else None, "trigger": self.trigger}

    def problem(self, model: LoadedModel, layout: SensorLayout | None = None) -> str | None:
        """Why ``model`` cannot serve the configured scene on ``layout`` (default: the device's), or None."""
        return scene_problem(model, self.cfg, layout or self.layout)

    def load(self, path: Path) -> LoadedModel:
        """Load a model file as the daemon does (validated, not yet warmed up: the watcher does that)."""

        ox = self.cfg.onnxruntime
        return load_model(path, max_bytes=self.cfg.model.max_bytes, intra_op_threads=ox.intra_op_threads,
                          allow_spinning=ox.allow_spinning, warm_up=False)

    def serve(self, model: LoadedModel, layout: SensorLayout) -> None:
        """Serve ``model`` for a device with ``layout`` without a watcher (embedding, tests). Raises
        ValueError when the model cannot serve the configured scene (the watcher's check, one line)."""
        problem = self.problem(model, layout)
        if problem:
            raise ValueError(f"model {model.model_id}: {problem}")
        self.layout = layout
        self.use(model)

    def start(self) -> None:
        """(Re)start the watcher on ``cfg.model.folder``; the newest valid model there serves at once."""
        if self.watcher is not None:
            self.watcher.stop()
        self.watcher = ModelWatcher(
            self.cfg.model.folder,
            loader=self.load,
            check=lambda m: self.problem(m),
            poll_interval=self.cfg.model.poll_interval_s,
            on_reject=self._rejected,
            decision_budget=self.cfg.model.decision_budget,
            quarantine=self.quarantine,
            said=self._said_rejections,
        )
        model = self.watcher.poll(require_stable=False)
        self.watcher.take()
        if model is not None:
            self.use(model)
        elif self.model is None:
            log.warning("no valid model in %s yet; waiting for one (frames are read, nothing is classified)",
                        self.cfg.model.folder)
            self.health.report_error(f"no model serves: no valid model in {self.cfg.model.folder} yet", "model")
        self.watcher.start()

    def stop(self, timeout: float = 0.5) -> None:
        if self.watcher is not None:
            self.watcher.stop(timeout=timeout)

    @property
    def pending(self) -> bool:
        """Whether the watcher holds a validated model that waits to serve."""
        return self.watcher is not None and (self.watcher.pending is not None or self.watcher.withdrawn)

    def take_pending(self) -> None:
        """Swap in the watcher's validated model (the caller waits until no window is open), or serve
        none when the serving file left the folder and nothing there can serve."""
        if self.watcher is not None:
            model = self.watcher.take()
            if model is not None:
                self.use(model)
            elif self.watcher.take_withdrawal() and self.model is not None:
                log.warning("model %s: its file left %s and no file there can serve; none serves until one is "
                            "dropped", self.model.model_id, self.cfg.model.folder)
                self.health.report_error(f"model {Path(self.model.path).name} left the model folder; no file there "
                                         "can serve", "model")
                self.drop()

    def use(self, model: LoadedModel) -> None:
        """Swap the serving model, announce it, say what starts its windows."""
        old = self.model
        if old is not None and old is not model:
            self._fallback = old
        self.model = model
        self.serve_model(model)
        self.loaded += 1
        self.health.resolve("model")
        if model.early_note:  # the full model serves; the heads it carried contradicted it
            log.warning("%s", model.early_note)
            self.health.report_error(model.early_note, "model")
        # the model announced last, also when a reload or a quarantine took it out before this one came
        previous, self._announced = self._announced, model
        self.announce(ModelAnnouncement.of(model, self.loaded, previous))
        what, settings = "swapped in" if old is not None else "serving", self._settings(model)
        log.info("model %s %s (%s, T=%d, classes %s; %s)", model.model_id, what, Path(model.path).name, model.meta.T,
                 ",".join(model.meta.classes), f"{settings.name} trigger" if settings else "continuous mode: a decision "
                 "every frame")  # settings come from the config, else the model: a swap may change the trigger
        view = served(settings, model.meta.pads, model.meta.classes)
        if line := swap_warning(Path(model.path).name, self._served, view):
            log.warning("%s", line)
        self._served = view
        self.show_trigger()

    def _settings(self, model: LoadedModel | None):
        """The trigger ``model`` is served with (None in continuous mode: every frame is classified)."""
        if self.cfg.scene.mode == "continuous":
            return None
        return resolve_trigger(self.cfg.trigger, model.meta.trigger if model is not None else None)

    def show_trigger(self) -> None:
        """The health view's ``trigger``: what starts a window now, with its main settings."""
        if self.cfg.scene.mode == "continuous":
            self.trigger = "continuous (a decision every frame)"
        else:
            self.trigger = trigger_text(self._settings(self.model))

    def drop(self) -> None:
        """No model serves (it does not fit a new scene or device); the watcher may bring another."""
        self.model = None
        self.serve_model(None)
        self.show_trigger()

    def fit_layout(self, layout: SensorLayout) -> None:
        """A device with a new layout: a model that does not fit it stops serving (one error line, and the
        health view's error until a model serves), and the folder's files are weighed again for it. Why
        again: a controller that comes back with another layout and then the original one must get the
        model that fits it back without a reload."""
        if layout == self.layout:
            return
        self.layout = layout
        model = self.model
        if model is not None and (problem := self.problem(model, layout)):
            log.error("model %s does not fit the device: %s; waiting for another model", model.model_id, problem)
            self.health.report_error(f"model {Path(model.path).name} does not fit the device: {problem}", "model")
            self.drop()
        if self.model is None and self.watcher is not None:
            self.watcher.rescan(keep_current=False)

    def refit(self, old: Config, new: Config) -> None:
        """A reloaded config: another device is weighed afresh when it streams; the new scene may not fit
        the model in use; new model settings restart the watcher."""
        self.cfg = new
        if new.device.url != old.device.url:
            self.layout = None  # the next device may have another layout
        self.show_trigger()  # a [trigger] or scene.mode the config now sets
        same_model = replace(new.model, shadow=old.model.shadow) == old.model  # the shadow folder is runtime.shadow's
        if new.scene == old.scene and same_model and new.onnxruntime == old.onnxruntime:
            return
        if self.model is not None and (problem := self.problem(self.model)):
            log.warning("the model in use does not fit the new scene; waiting for one that does")
            self.health.report_error(f"no model serves: the model in use does not fit the new scene ({problem})",
                                     "model")
            self.drop()
        if not same_model or new.onnxruntime != old.onnxruntime:
            self.start()
        elif self.watcher is not None:  # a file rejected under the old scene may fit the new one
            self.watcher.rescan(keep_current=self.model is not None)

    def quarantine_now(self, model: LoadedModel, reason: str) -> None:
        """Never load this version of the model's file again (also after a restart), without a swap:
        from another thread, before the process exits over a decision that would not stop."""
        (self.watcher or self.quarantine).quarantine_file(Path(model.path), reason)

    def take_out_of_service(self, model: LoadedModel, reason: str) -> None:
        """A model broke the output contract at run time: one line, never load this file version
        again (also after a restart), and serve the model it replaced, or none."""
        h = self.health
        self.quarantined += 1
        self.quarantine_now(model, reason)
        fallback, self._fallback = self._fallback, None
        if fallback is not None and self.problem(fallback):
            fallback = None
        h.report_error(f"model {Path(model.path).name} taken out of service: {reason}", "quarantine")
        what = "no model serves until the watcher finds the next newest valid file or a new one is dropped"
        if fallback is not None:
            what = f"model {fallback.model_id} ({Path(fallback.path).name}) serves again"
        log.error("model %s (%s) taken out of service: %s; it is not loaded again until the file changes; %s",
                  model.model_id, Path(model.path).name, reason, what)
        self.drop()
        if fallback is not None:
            self.use(fallback)  # announced to the sinks like any model that starts serving
        elif self.watcher is not None:
            self.watcher.reconsider_older()

    def _rejected(self, rejection: Rejection) -> None:
        """Counted once per file version and reason; the health view shows it again each time it is weighed."""
        if not rejection.repeat:
            self.rejected += 1
        self.health.report_error(f"model {rejection.path.name} rejected: {rejection.reason}", "model")
