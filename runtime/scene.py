"""Does a model fit the scene? The daemon's and ``run --check``'s one answer, with what to do next.

``scene.pads = "model"`` (the default) follows the serving model's pads; any other value pins
the scene, and a model trained for other pads is refused. Every refusal names the fix.
"""

from __future__ import annotations

from typing import Any

from firmware_io.layout import LayoutError, SensorLayout
from runtime.config import FOLLOW_MODEL, Config, SceneConfig

__all__ = ["events_problem", "scene_pads", "scene_problem"]

RELOAD_HINT = "and reload (systemctl reload handover, i.e. SIGHUP)"


def _where(cfg: Config) -> str:
    return cfg.source or "the config"


def _pad_list(pads) -> str:
    return ",".join(str(int(p)) for p in pads)


def scene_pads(scene: SceneConfig, model: Any, layout: SensorLayout) -> tuple[int, ...]:
    """The matrices the hot path keeps: the scene's selection, or the model's (all pads while none serves)."""
    if scene.pads != FOLLOW_MODEL:
        return layout.pads(scene.pads)
    return layout.pads(list(model.meta.pads) if model is not None else "all")


def events_problem(model: Any, events: tuple[str, ...], cfg: Config | None = None) -> str | None:
    """``scene.events: 'pul' is not a class of model X (classes: ...): ...``, or None."""
    classes = list(model.meta.classes)
    missing = [e for e in events if e not in classes]
    if not missing:
        return None
    names = ", ".join(repr(e) for e in missing)
    verb = "is not a class" if len(missing) == 1 else "are not classes"
    where = _where(cfg) if cfg is not None else "the config"
    return (f"scene.events: {names} {verb} of model {model.model_id} (classes: {', '.join(classes)}); "
            f"list only these classes in scene.events in {where} {RELOAD_HINT}, or drop a model that has them")


def _pads_problem(meta: Any, cfg: Config, lay: SensorLayout) -> str | None:
    if cfg.scene.pads == FOLLOW_MODEL:
        try:
            lay.pads(list(meta.pads))
        except LayoutError:
            return (f"model expects pads {list(meta.pads)}, the device has {lay.n_matrices} pads "
                    f"(0..{lay.n_matrices - 1}); train a model on recordings of this hand")
        return None
    try:
        pads = lay.pads(cfg.scene.pads)
    except LayoutError as exc:
        return f"scene.pads: {exc}; fix scene.pads in {_where(cfg)} {RELOAD_HINT}"
    if tuple(meta.pads) != tuple(pads):
        return (f"model expects pads {list(meta.pads)}, the scene uses {list(pads)} (scene.pads = "
                f"{cfg.scene.pads!r}); set scene.pads = \"{FOLLOW_MODEL}\" (follow the model) in {_where(cfg)} "
                f"{RELOAD_HINT}, or train with --pads {lay.selection_name(pads) or _pad_list(pads)}")
    return None


def scene_problem(model: Any, cfg: Config, layout: SensorLayout | None, check_events: bool = True) -> str | None:
    """Why a model cannot serve this scene (pads, channels, classes, mode) and what to do, or None."""
    meta = model.meta
    lay = layout or SensorLayout.sdh2()
    problem = _pads_problem(meta, cfg, lay)
    if problem:
        return problem
    pads = lay.pads(list(meta.pads))
    n = sum(lay.pad_sizes(pads))
    if meta.n_channels != n:
        return (f"model expects {meta.n_channels} taxel columns, the device's pads {list(pads)} have {n}; "
                "the model was trained on a hand with other pad sizes: train on recordings of this hand")
    if meta.fullscale > lay.fullscale:
        return (f"model fullscale {meta.fullscale:g} is more than the device's pads report ({lay.fullscale:g}): "
                "its trigger levels could never be reached; train on recordings of this hand")
    if check_events and (problem := events_problem(model, cfg.scene.events, cfg)):
        return problem
    if cfg.scene.mode == "continuous" and meta.dormant_class is None:
        return ("scene.mode = 'continuous' needs a model with a dormant class; this one has none: set "
                f"scene.mode = \"trigger\" in {_where(cfg)} {RELOAD_HINT}, or drop a model with a dormant class")
    return None
