"""The model file contract: one ONNX graph from raw frames to the decision.

A model file is one self-contained ONNX graph (no external data) with

- input ``frames`` float32 ``[N, T, C]`` (N dynamic or symbolic, never fixed; C = taxels of the
  model's pads in wire order),
- outputs ``label`` int64 ``[N]`` (index into ``classes``) and ``scores`` float32
  ``[N, n_classes]`` (scikit-learn's one-vs-rest scores: one-vs-one votes + confidence/(3(|conf|+1))),
- metadata: ``metadata_props["handover"]`` = JSON (see ``REQUIRED_KEYS``); ``classes`` a list of
  names; for a BoW graph K and W agree with the codeword kernel initializers,
- operators of the standard domains only (``ai.onnx``, ``ai.onnx.ml``).

Every check here refuses with one ``ModelContractError`` naming what is wrong; runtime.model
loads a file and runs them before the daemon trusts it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from firmware_io.errors import HandoverError
from firmware_io.layout import FULL_SCALE_12BIT
from firmware_io.trigger_level import is_trigger_level
from runtime.early import EARLY_KEY, EarlySpec, EarlySpecError, head_outputs, is_head_output
from runtime.trigger_settings import recorded_problems

__all__ = [
    "ALLOWED_DOMAINS", "CODEWORD_KERNEL", "DEFAULT_MAX_BYTES", "INPUT_NAME", "METADATA_KEY", "OUTPUT_NAMES",
    "REAL_FALSE_KEY", "SCHEMA_VERSION", "ModelContractError", "ModelMeta", "ModelUnreadableError", "check_bow_params",
    "check_io", "early_spec", "optional_table", "other_file_kind", "real_false_events",
]

SCHEMA_VERSION = 1
METADATA_KEY = "handover"
INPUT_NAME = "frames"
OUTPUT_NAMES = ("label", "scores")
ALLOWED_DOMAINS = frozenset({"", "ai.onnx", "ai.onnx.ml"})
DEFAULT_MAX_BYTES = 64 * 1024 * 1024
SAMPLE_RATES_HZ = (1.0, 1000.0)
"""The sample rates a model may be trained at (the SDH-2 streams ~32 Hz, fast controllers ~70 Hz):
outside them the daemon's period arithmetic means nothing (at 1e300 Hz every frame is a break in
the stream; at 0.001 Hz no trigger fires), so such a model is refused at load."""
"""A BoW + SVM graph is a few hundred kB; anything near this limit is not one of ours."""

REQUIRED_KEYS = (
    "schema_version",
    "classes",
    "T",
    "W",
    "K",
    "pads",
    "n_channels",
    "pad_sizes",
    "fullscale",
    "trigger",
    "sample_rate_hz",
    "score",
    "dormant_class",
    "training",
    "evaluation",
)
TRAINING_KEYS = ("data_fingerprint", "n_trials", "project_version", "date")


class ModelContractError(HandoverError, ValueError):
    """A model file that breaks the contract; the message names the file and the problem."""


class ModelUnreadableError(ModelContractError):
    """Bytes that are not (yet) a whole model: empty, truncated, no graph onnxruntime can load, no
    metadata. What a file still being copied looks like, so the watcher retries it for a while."""


@dataclass(frozen=True)
class ModelMeta:
    """The metadata a model file carries (``metadata_props["handover"]``)."""

    schema_version: int
    classes: tuple[str, ...]
    T: int
    W: int
    K: int
    pads: tuple[int, ...]
    n_channels: int
    pad_sizes: tuple[int, ...]
    fullscale: float
    trigger: dict
    sample_rate_hz: float
    score: str
    dormant_class: str | None
    training: dict
    evaluation: dict
    extra: dict = field(default_factory=dict)
    """Keys beyond the required ones (e.g. ``feature_groups``, ``kernel``, ``reference``)."""

    @property
    def n_classes(self) -> int:
        return len(self.classes)

    def to_dict(self) -> dict:
        d = {key: getattr(self, key) for key in REQUIRED_KEYS}
        d["classes"], d["pads"], d["pad_sizes"] = list(self.classes), list(self.pads), list(self.pad_sizes)
        return {**self.extra, **d}

    @classmethod
    def from_dict(cls, d: dict) -> ModelMeta:
        """Validate the metadata on its own (types, ranges, internal consistency)."""
        if not isinstance(d, dict):
            raise ModelContractError("metadata is not a JSON object")
        missing = [k for k in REQUIRED_KEYS if k not in d]
        if missing:
            raise ModelContractError(f"metadata lacks {', '.join(missing)}")
        if d["schema_version"] != SCHEMA_VERSION:
            raise ModelContractError(f"metadata schema_version {d['schema_version']!r}, this runtime reads {SCHEMA_VERSION}")
        for key in ("classes", "pads", "pad_sizes"):
            if not isinstance(d[key], list):
                raise ModelContractError(f"metadata: {key} must be a list, got {d[key]!r}")
        bad = [c for c in d["classes"] if not isinstance(c, str)]
        if bad:
            raise ModelContractError(f"metadata: classes must be names (strings), got {bad[0]!r}")
        try:
            classes = tuple(d["classes"])
            pads = tuple(_int(p, "pads") for p in d["pads"])
            pad_sizes = tuple(_int(p, "pad_sizes") for p in d["pad_sizes"])
            meta = cls(
                schema_version=SCHEMA_VERSION,
                classes=classes,
                T=_int(d["T"], "T"),
                W=_int(d["W"], "W"),
                K=_int(d["K"], "K"),
                pads=pads,
                n_channels=_int(d["n_channels"], "n_channels"),
                pad_sizes=pad_sizes,
                fullscale=_positive(d["fullscale"], "fullscale"),
                trigger=_dict(d["trigger"], "trigger"),
                sample_rate_hz=_sample_rate(d["sample_rate_hz"]),
                score=str(d["score"]),
                dormant_class=None if d["dormant_class"] is None else str(d["dormant_class"]),
                training=_dict(d["training"], "training"),
                evaluation=_dict(d["evaluation"], "evaluation"),
                extra={k: v for k, v in d.items() if k not in REQUIRED_KEYS},
            )
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ModelContractError):
                raise
            raise ModelContractError(f"metadata: {exc}") from exc
        meta._check()
        return meta

    def _check(self) -> None:
        problems = []
        if len(self.classes) < 2 or len(set(self.classes)) != len(self.classes):
            problems.append(f"classes {list(self.classes)} must be at least 2 distinct names")
        if self.dormant_class is not None and self.dormant_class not in self.classes:
            problems.append(f"dormant_class {self.dormant_class!r} is not one of the classes")
        if self.W < 1 or self.K < 1:
            problems.append(f"W={self.W} and K={self.K} must be >= 1")
        if self.T < 2:
            problems.append(f"T={self.T} must be a window of at least 2 frames (the trained window length; "
                            "re-export the model)")
        elif self.T - 1 < self.W:
            problems.append(f"T={self.T} leaves fewer than W={self.W} derivative steps")
        if not self.pads or len(set(self.pads)) != len(self.pads) or min(self.pads) < 0:
            problems.append(f"pads {list(self.pads)} must be distinct matrix indices")
        if len(self.pad_sizes) != len(self.pads) or min(self.pad_sizes, default=0) < 1:
            problems.append(f"pad_sizes {list(self.pad_sizes)} must give a positive size for each of the pads {list(self.pads)}")
        if sum(self.pad_sizes) != self.n_channels:
            problems.append(f"n_channels={self.n_channels} != sum(pad_sizes)={sum(self.pad_sizes)}")
        if self.fullscale < 1:
            problems.append(f"fullscale {self.fullscale:g} is below 1, not a 12-bit pad's full scale (1 to "
                            f"{FULL_SCALE_12BIT}); trigger levels and the onset floor would be ~0: re-export the model")
        elif not self.fullscale <= FULL_SCALE_12BIT:
            problems.append(f"fullscale {self.fullscale:g} is more than the pads can report ({FULL_SCALE_12BIT}, "
                            "12-bit); no press would ever reach the trigger: re-export the model")
        fraction = self.trigger.get("fraction")
        if not is_trigger_level(fraction):
            problems.append(f"trigger.fraction {fraction!r} must be a number in (0, 1)")
        problems += recorded_problems(self.trigger)
        missing = [k for k in TRAINING_KEYS if k not in self.training]
        if missing:
            problems.append(f"training lacks {', '.join(missing)}")
        if problems:
            raise ModelContractError("metadata: " + "; ".join(problems))


def _int(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ModelContractError(f"metadata: {name} must be an integer, got {value!r}")
    return value


def _positive(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise ModelContractError(f"metadata: {name} must be a positive number, got {value!r}")
    return float(value)


def _sample_rate(value) -> float:
    rate = _positive(value, "sample_rate_hz")
    low, high = SAMPLE_RATES_HZ
    if not low <= rate <= high:
        raise ModelContractError(f"metadata: sample_rate_hz must be between {low:g} and {high:g} Hz, got {value!r}")
    return rate


def _dict(value, name: str) -> dict:
    if not isinstance(value, dict):
        raise ModelContractError(f"metadata: {name} must be an object, got {type(value).__name__}")
    return value


def early_spec(meta: ModelMeta) -> EarlySpec | None:
    """The metadata's early heads, or None; ModelContractError (one line) when they make no sense."""
    if EARLY_KEY not in meta.extra:
        return None
    try:
        return EarlySpec.from_meta(meta.extra[EARLY_KEY], meta.T, meta.classes)
    except EarlySpecError as exc:
        raise ModelContractError(f"metadata: {exc}") from None


def check_io(session, meta: ModelMeta, spec: EarlySpec | None) -> None:
    inputs, outputs = session.get_inputs(), session.get_outputs()
    if [i.name for i in inputs] != [INPUT_NAME]:
        raise ModelContractError(f"inputs {[i.name for i in inputs]}, expected exactly [{INPUT_NAME!r}]")
    inp = inputs[0]
    if inp.type != "tensor(float)":
        raise ModelContractError(f"input {INPUT_NAME!r} is {inp.type}, expected tensor(float)")
    if len(inp.shape) != 3 or list(inp.shape[1:]) != [meta.T, meta.n_channels]:
        raise ModelContractError(
            f"input {INPUT_NAME!r} has shape {inp.shape}, metadata says [N, T={meta.T}, C={meta.n_channels}]"
        )
    if isinstance(inp.shape[0], int):
        raise ModelContractError(
            f"input {INPUT_NAME!r} has a fixed batch size of {inp.shape[0]}; the contract needs a dynamic (or "
            "symbolic) batch dimension N, since the daemon runs single windows and tools run batches"
        )
    names = [o.name for o in outputs]
    heads = [name for p in (spec.points if spec else ()) for name in head_outputs(p)]
    base = [n for n in names if not is_head_output(n)]
    if sorted(base) != sorted(OUTPUT_NAMES):
        raise ModelContractError(f"outputs {base}, expected {list(OUTPUT_NAMES)}")
    found = sorted(n for n in names if is_head_output(n))
    if found != sorted(heads):
        says = f"early.points {list(spec.points)}" if spec else "no early heads"
        raise ModelContractError(f"the graph's early-head outputs {found} disagree with the metadata ({says}); "
                                 "re-export the model")
    by_name = {o.name: o for o in outputs}
    for label_name, scores_name in [OUTPUT_NAMES, *(head_outputs(p) for p in (spec.points if spec else ()))]:
        label, scores = by_name[label_name], by_name[scores_name]
        if label.type != "tensor(int64)" or len(label.shape) != 1:
            raise ModelContractError(f"output {label_name!r} is {label.type} {label.shape}, expected tensor(int64) [N]")
        if scores.type != "tensor(float)" or len(scores.shape) != 2 or scores.shape[1] != meta.n_classes:
            raise ModelContractError(
                f"output {scores_name!r} is {scores.type} {scores.shape}, expected tensor(float) [N, {meta.n_classes}] "
                f"(one score per class of {list(meta.classes)})"
            )


CODEWORD_KERNEL = "codeword_kernel"
"""Name prefix of a BoW graph's codeword convolution kernels ``[K, 1, W (+1 when the derivative is
folded), 1]``, one per window length (trainer.onnx_export)."""


def optional_table(value) -> dict:
    """An optional metadata object (``graph``, ``features``, ``svm``), or {} when a hand-edited or
    hostile file holds something else there (the loader and ``inspect`` must not trip on it)."""
    return value if isinstance(value, dict) else {}


def check_bow_params(meta: ModelMeta, initializer_dims: dict[str, tuple[int, ...]]) -> None:
    """K and W of the metadata against the codeword kernels of a BoW graph (read from the wire).

    Only for ``model_kind == "bow_svm"``: other kinds (flattened-series SVM) have no codebook and
    K = W = 1 by convention.
    """
    if meta.extra.get("model_kind") != "bow_svm":
        return
    kernels = [dims for name, dims in initializer_dims.items() if name.startswith(CODEWORD_KERNEL)]
    if not kernels:
        raise ModelContractError(f"metadata says a BoW model but the graph has no {CODEWORD_KERNEL} initializer")
    if any(len(d) != 4 for d in kernels):
        raise ModelContractError(f"codeword kernels of shape {kernels}, expected [K, 1, W, 1]")
    fold = bool(optional_table(meta.extra.get("graph")).get("fold_derivative", False))
    words = sorted({d[0] for d in kernels})
    windows = sorted(d[2] - int(fold) for d in kernels)
    if words != [meta.K]:
        raise ModelContractError(f"metadata K={meta.K}, but the graph's codebook has {', '.join(map(str, words))} words")
    if max(windows) != meta.W:
        raise ModelContractError(f"metadata W={meta.W}, but the graph's longest codeword window is {max(windows)}")
    listed = optional_table(meta.extra.get("features")).get("windows")
    if isinstance(listed, list) and sorted(listed) != windows:
        raise ModelContractError(f"metadata features.windows {listed}, but the graph's codeword windows are {windows}")


REAL_FALSE_KEY = "real_false_events"
"""Metadata key: per stream setting (runtime.stream_settings.SETTINGS) the false events per hour the model
raised on REAL idle signals, ``{"onset_dormant": {"per_hour": 0.4, "events": 1, "hours": 2.5, "data": "..."}}``
(``data``: what was replayed and how). A setting not listed is unmeasured: synthetic idle never counts."""
REAL_FALSE_FIELDS = ("per_hour", "events", "hours")


def real_false_events(meta: ModelMeta) -> dict[str, dict]:
    """The settings with a real false-event rate, each ``{per_hour, events, hours, data}``; an entry that is
    not one (hand-edited, older file) is left out, so it reads as unmeasured and never stops a load."""
    table = optional_table(meta.extra.get(REAL_FALSE_KEY))
    out = {}
    for setting, entry in table.items():
        if not isinstance(entry, dict):
            continue
        values = [entry.get(k) for k in REAL_FALSE_FIELDS]
        if all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v >= 0 for v in values) \
                and values[2] > 0:
            out[str(setting)] = {"per_hour": float(values[0]), "events": int(values[1]), "hours": float(values[2]),
                                 "data": str(entry.get("data", ""))}
    return out


def other_file_kind(data: bytes) -> str | None:
    """What a file that is no ONNX model is, when it is one of this project's other files."""
    if data.startswith(b"PK\x03\x04"):  # .hrec recordings are zip archives of arrays
        return "a recording (a zip archive such as .hrec), not a model"
    if data[:1] == b"\x80":  # a pickle: model.joblib, the float64 reference train writes beside the .onnx
        return "a pickle such as the model.joblib train writes beside the .onnx, not the model"
    return None
