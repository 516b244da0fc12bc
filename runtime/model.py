"""The model file contract and its loader: one ONNX graph from raw frames to the decision.

A model file is one self-contained ONNX graph (no external data) with

- input ``frames`` float32 ``[N, T, C]`` (N dynamic or symbolic, never fixed; C = taxels of the
  model's pads in wire order),
- outputs ``label`` int64 ``[N]`` (index into ``classes``) and ``scores`` float32
  ``[N, n_classes]`` (scikit-learn's one-vs-rest scores: one-vs-one votes + confidence/(3(|conf|+1))),
- metadata: ``metadata_props["handover"]`` = JSON (see ``REQUIRED_KEYS``); ``classes`` a list of
  names; for a BoW graph K and W agree with the codeword kernel initializers,
- operators of the standard domains only (``ai.onnx``, ``ai.onnx.ml``).

The loader checks all of it before the daemon trusts a file and refuses with one
``ModelContractError`` naming what is wrong. It needs onnxruntime only: metadata comes from
``session.get_modelmeta()``, operator domains and external-data references from a small
protobuf wire reader (``runtime.onnx_wire``), so the robot PC never installs ``onnx``.
"""

from __future__ import annotations

import hashlib
import json
import math
import threading
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from firmware_io.layout import FULL_SCALE_12BIT
from firmware_io.trigger_level import is_trigger_level
from runtime.early import EARLY_KEY, EarlySpec, EarlySpecError, head_outputs, is_head_output
from runtime.onnx_wire import WireError, keep_outputs, summarize
from runtime.output_check import DEFAULT_BUDGET_FRACTION, probe
from runtime.trigger_settings import recorded_problems

__all__ = [
    "CODEWORD_KERNEL", "INPUT_NAME", "METADATA_KEY", "OUTPUT_NAMES", "SCHEMA_VERSION", "LoadedModel",
    "ModelContractError", "ModelInputError", "ModelMeta", "ModelUnreadableError", "load_model", "optional_table",
    "session_options"
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


class ModelContractError(ValueError):
    """A model file that breaks the contract; the message names the file and the problem."""


class ModelUnreadableError(ModelContractError):
    """Bytes that are not (yet) a whole model: empty, truncated, no graph onnxruntime can load, no
    metadata. What a file still being copied looks like, so the watcher retries it for a while."""


WARM_UP_BOUND_S = 10.0
"""Longest a model's whole warm-up may take (a few dozen decisions; the slowest model a budget lets
through takes well under a second)."""


class DecisionEnded(RuntimeError):
    """A decision was ended from outside (``LoadedModel.end_decision``): the model ran too long."""


class ModelInputError(ValueError):
    """Input frames the model refuses (wrong shape, non-finite values)."""


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


def session_options(intra_op_threads: int = 1, allow_spinning: bool = False):
    """ORT options for a latency-bound daemon: one thread, no spinning (flat tail on a busy core).

    Chosen by measurement (``results/latency.md``, one window, sessions interleaved): for a BoW
    graph ``ORT_ENABLE_EXTENDED`` decides faster than ``ORT_ENABLE_ALL``, whose layout pass turns the
    codeword Conv into NCHWc with reorder nodes around it. For the default (feature) graph the
    optimisation levels, the arena, denormals as zero and an IOBinding made no difference beyond
    the run-to-run spread; without the memory pattern it was slower with a long tail, so that stays on."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = int(intra_op_threads)
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED
    spin = "1" if allow_spinning else "0"
    opts.add_session_config_entry("session.intra_op.allow_spinning", spin)
    opts.add_session_config_entry("session.inter_op.allow_spinning", spin)
    opts.log_severity_level = 3
    return opts


class LoadedModel:
    """A validated model, ready to run. ``run`` refuses bad input with ModelInputError."""

    def __init__(self, path: Path, session, meta: ModelMeta, model_id: str, n_nodes: int, n_bytes: int,
                 early: EarlySpec | None = None, head_sessions: list | None = None):
        self.path = path
        self.meta = meta
        self.model_id = model_id
        self.n_nodes = n_nodes
        self.n_bytes = n_bytes
        self._session = session
        self._shape = (meta.T, meta.n_channels)
        self._stage = _aligned((1, *self._shape))
        """One window is copied here before it runs (``run_trusted`` says why)."""
        self._staging = threading.Lock()
        self.early = early
        """The early heads and their rule (runtime.early), or None: the model answers at T only."""
        self._head_sessions = list(head_sessions or [session] * len(self.early.points if self.early else ()))
        """One session per early head (``load_model`` prunes the file per head), or the one graph's."""
        self._head_outputs = [head_outputs(p) for p in (self.early.points if self.early else ())]
        """Each head's output names, made once (not per decision)."""
        self.running_since: float | None = None
        """``time.perf_counter()`` when the decision under way began, None between decisions (read by
        runtime.decision_guard from its own thread)."""
        self._cpu: tuple[int, float] | None = None
        """The deciding thread's CPU clock and its reading when the decision under way began."""
        self._clocks: dict[int, int] = {}
        """Thread ident -> its CPU clock id (``decision_cpu_s``)."""
        self.ended: str | None = None
        """Why ``end_decision`` ended this model's decisions (it then runs no more), or None."""
        self._options: Any = None
        """onnxruntime RunOptions of every run, made on the first one (``end_decision`` ends it)."""

    def __repr__(self) -> str:
        return f"LoadedModel({self.path.name}, id={self.model_id}, classes={list(self.meta.classes)})"

    def check_input(self, x) -> np.ndarray:
        """float32 C-contiguous ``[N, T, C]`` with only finite values, or ModelInputError."""
        arr = np.ascontiguousarray(x, dtype=np.float32)
        if arr.ndim == 2 and arr.shape == self._shape:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[1:] != self._shape or arr.shape[0] < 1:
            raise ModelInputError(
                f"model {self.model_id} expects frames [N, {self._shape[0]}, {self._shape[1]}], got {list(np.shape(x))}"
            )
        if not np.isfinite(arr).all():
            raise ModelInputError(f"model {self.model_id}: input frames contain NaN or infinity; refused")
        return arr

    def run(self, x, check: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Labels int64 ``[N]`` (indices into meta.classes) and scores float32 ``[N, n_classes]``.

        ``check=False`` is ``run_trusted``: for callers that build ``x`` themselves.
        """
        if not check:
            return self.run_trusted(x)
        arr = self.check_input(x)
        labels, scores = self._session.run(OUTPUT_NAMES, {INPUT_NAME: arr})
        return labels, scores

    def run_trusted(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``run`` without ``check_input``: for the daemon's hot path, whose windows are float32
        ``[N, T, C]`` copies of uint16 frames (always finite, right shape by construction). No
        finiteness scan; onnxruntime still refuses a wrong dtype or shape (with its own error).

        One ``[1, T, C]`` float32 window is first copied to one 64-byte aligned array: onnxruntime's
        kernels sum in an order that depends on where the input starts in memory, so a ring window's
        offset changed the scores' last bits; this way one window gives one answer, bit for bit,
        wherever the ring holds it (a replay and the service agree). A second caller at the same
        time, a batch or another dtype run as given."""
        return self._run(self._session, OUTPUT_NAMES, x)

    def end_decision(self, reason: str) -> None:
        """End the decision under way from another thread (a graph that runs too long: onnxruntime's
        RunOptions.terminate is checked between nodes and loop steps); this model runs no more."""
        self.ended = reason
        self._run_options().terminate = True

    def _run_options(self) -> Any:
        if self._options is None:
            import onnxruntime as ort

            options = ort.RunOptions()
            options.log_severity_level = 4  # the failure is reported in one line by the caller
            self._options = options
        return self._options

    def run_head(self, index: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The early head ``index`` (of ``early.points``) on the newest T frames ``x`` ``[1, T, C]``
        float32 (it reads their last ``p`` rows); like ``run_trusted``, no input check."""
        return self._run(self._head_sessions[index], self._head_outputs[index], x)

    def _run(self, session: Any, outputs: tuple[str, str], x: Any) -> tuple[np.ndarray, np.ndarray]:
        if self.ended is not None:
            raise DecisionEnded(self.ended)
        stage, options = self._stage, self._run_options()
        clock = self._thread_clock()
        self._cpu = None if clock is None else (clock, time.clock_gettime(clock))
        self.running_since = time.perf_counter()
        try:
            if (isinstance(x, np.ndarray) and x.shape == stage.shape and x.dtype == stage.dtype
                    and self._staging.acquire(False)):
                try:
                    stage[...] = x
                    labels, scores = session.run(outputs, {INPUT_NAME: stage}, options)
                finally:
                    self._staging.release()
            else:
                labels, scores = session.run(outputs, {INPUT_NAME: x}, options)
        except Exception:
            if self.ended is not None:
                raise DecisionEnded(self.ended) from None
            raise
        finally:
            self.running_since = None
        if self.ended is not None:
            raise DecisionEnded(self.ended)
        return labels, scores

    def _thread_clock(self) -> int | None:
        """The calling thread's CPU clock (None where the platform has none)."""
        ident = threading.get_ident()
        clock = self._clocks.get(ident)
        if clock is None and hasattr(time, "pthread_getcpuclockid"):
            try:
                clock = self._clocks[ident] = time.pthread_getcpuclockid(ident)
            except OSError:
                return None
        return clock

    def decision_cpu_s(self) -> float | None:
        """CPU seconds the deciding thread has spent in the decision under way, or None (no decision
        under way, or no thread CPU clock here). Read from another thread: a thread that only waited for
        a core (a busy machine) has spent little; a graph that hangs spends it all."""
        cpu = self._cpu
        if cpu is None or self.running_since is None:
            return None
        try:
            return time.clock_gettime(cpu[0]) - cpu[1]
        except OSError:  # the thread ended meanwhile
            return None

    def warm_up(self, budget_fraction: float | None = DEFAULT_BUDGET_FRACTION, bound_s: float = WARM_UP_BOUND_S) -> None:
        """Run realistic windows (so the first real inference does not pay for allocations), check
        every answer against the output contract and one decision against the time budget
        (``budget_fraction`` of the sample period; None: not timed). ModelContractError if not,
        also when the whole warm-up runs past ``bound_s`` (a graph that hangs on pressed pads would
        otherwise hold the watcher, the daemon's start and ``run --check`` for good)."""
        reason = f"the warm-up ran longer than {bound_s:g} s and was ended (a graph that hangs on pressed pads?)"
        timer = threading.Timer(bound_s, self.end_decision, args=(reason,))
        timer.daemon = True
        timer.start()
        try:
            self._warm_up(budget_fraction)
        except DecisionEnded as exc:
            raise ModelContractError(f"model {self.path}: {exc}") from None
        finally:
            timer.cancel()

    def _warm_up(self, budget_fraction: float | None) -> None:
        meta = self.meta
        problem = probe(self.run_trusted, meta.T, meta.n_channels, meta.n_classes, meta.fullscale,
                        1.0 / meta.sample_rate_hz, budget_fraction)
        if problem:
            raise ModelContractError(f"model {self.path}: {problem}")
        for index, point in enumerate(self.early.points if self.early else ()):
            problem = probe(partial(self.run_head, index), meta.T, meta.n_channels, meta.n_classes, meta.fullscale,
                            1.0 / meta.sample_rate_hz, budget_fraction)
            if problem:
                raise ModelContractError(f"model {self.path}: early head at {point} frames {problem}")


def early_spec(meta: ModelMeta) -> EarlySpec | None:
    """The metadata's early heads, or None; ModelContractError (one line) when they make no sense."""
    if EARLY_KEY not in meta.extra:
        return None
    try:
        return EarlySpec.from_meta(meta.extra[EARLY_KEY], meta.T)
    except EarlySpecError as exc:
        raise ModelContractError(f"metadata: {exc}") from None


def _aligned(shape: tuple[int, ...]) -> np.ndarray:
    """float32 zeros of ``shape`` starting on a 64-byte boundary."""
    n = int(np.prod(shape))
    raw = np.zeros(n + 16, dtype=np.float32)
    start = (-raw.ctypes.data % 64) // 4
    return raw[start : start + n].reshape(shape)


def _check_io(session, meta: ModelMeta, spec: EarlySpec | None) -> None:
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


def _check_bow_params(meta: ModelMeta, initializer_dims: dict[str, tuple[int, ...]]) -> None:
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


def _other_file_kind(data: bytes) -> str | None:
    """What a file that is no ONNX model is, when it is one of this project's other files."""
    if data.startswith(b"PK\x03\x04"):  # .hrec recordings are zip archives of arrays
        return "a recording (a zip archive such as .hrec), not a model"
    if data[:1] == b"\x80":  # a pickle: model.joblib, the float64 reference train writes beside the .onnx
        return "a pickle such as the model.joblib train writes beside the .onnx, not the model"
    return None


def load_model(
    path: str | Path,
    max_bytes: int = DEFAULT_MAX_BYTES,
    intra_op_threads: int = 1,
    allow_spinning: bool = False,
    warm_up: bool = True,
    decision_budget: float | None = None,
) -> LoadedModel:
    """Read, validate and open a model file; any breach raises ModelContractError naming it.

    ``warm_up`` checks the output contract on realistic windows; ``decision_budget`` (a fraction
    of the sample period, e.g. 0.1) also refuses a model whose decision is slower (the daemon's
    rule; offline tools that measure speed themselves leave it None)."""
    import onnxruntime as ort

    path = Path(path)
    where = f"model {path}"
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise ModelContractError(f"{where}: {size} bytes exceeds the limit of {max_bytes}")
        data = path.read_bytes()
    except OSError as exc:
        raise ModelContractError(f"{where}: cannot read ({exc.strerror or exc})") from exc
    if len(data) > max_bytes:
        raise ModelContractError(f"{where}: {len(data)} bytes exceeds the limit of {max_bytes}")
    if not data:
        raise ModelUnreadableError(f"{where}: empty file")
    try:
        wire = summarize(data)
    except WireError as exc:
        other = _other_file_kind(data)
        if other:
            raise ModelUnreadableError(f"{where}: this is {other}; give a .onnx model") from exc
        raise ModelUnreadableError(f"{where}: not an ONNX model or truncated ({exc})") from exc
    if wire.external_data:
        raise ModelContractError(f"{where}: references external data; a model must be one self-contained file")
    if wire.nan_initializers:
        names = ", ".join(wire.nan_initializers[:3]) + (" ..." if len(wire.nan_initializers) > 3 else "")
        raise ModelContractError(f"{where}: constant(s) {names} hold NaN (a damaged file or a model fitted on "
                                 "NaN); export it again from its .joblib or train it again")
    foreign = sorted((wire.opset_domains | wire.node_domains) - ALLOWED_DOMAINS)
    if foreign:
        raise ModelContractError(f"{where}: uses non-standard operator domain(s) {foreign}; allowed: ai.onnx, ai.onnx.ml")
    try:
        # enable_fallback=0: on a failure onnxruntime's Python wrapper would otherwise print an
        # "EP Error" banner with print(), i.e. into the daemon's stdout event stream.
        session = ort.InferenceSession(
            data, sess_options=session_options(intra_op_threads, allow_spinning), providers=["CPUExecutionProvider"],
            enable_fallback=0,
        )
    except Exception as exc:  # onnxruntime raises several unrelated types for a bad graph
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ModelUnreadableError(f"{where}: onnxruntime cannot load it: {first}") from exc
    try:
        raw = session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
    except UnicodeDecodeError as exc:  # onnxruntime decodes metadata strings as UTF-8 for Python
        raise ModelContractError(f"{where}: metadata is not valid UTF-8 (byte {exc.start}); damaged file?") from None
    if raw is None:
        raise ModelUnreadableError(f"{where}: no {METADATA_KEY!r} metadata (not a handover model)")
    try:
        meta_dict = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise ModelContractError(f"{where}: metadata is not valid JSON ({exc.msg} at {exc.pos})") from exc
    except RecursionError:
        raise ModelContractError(f"{where}: metadata is nested too deeply") from None
    try:
        meta = ModelMeta.from_dict(meta_dict)
        spec = early_spec(meta)
        _check_io(session, meta, spec)
        _check_bow_params(meta, wire.initializer_dims)
    except ModelContractError as exc:
        raise ModelContractError(f"{where}: {exc}") from exc
    except UnicodeDecodeError as exc:  # input/output names of a damaged file
        raise ModelContractError(f"{where}: a name in the graph is not valid UTF-8 (byte {exc.start}); damaged file?") from None
    model_id = hashlib.sha256(data).hexdigest()[:12]
    heads: list = []
    if spec is not None:  # one session per head: onnxruntime runs every node of a graph
        parts = [OUTPUT_NAMES, *(head_outputs(p) for p in spec.points)]
        try:
            session, *heads = (ort.InferenceSession(keep_outputs(data, names), sess_options=session_options(
                intra_op_threads, allow_spinning), providers=["CPUExecutionProvider"], enable_fallback=0)
                for names in parts)
        except Exception as exc:  # a damaged graph whose parts do not stand alone
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ModelContractError(f"{where}: its early heads do not load on their own: {first}") from exc
    model = LoadedModel(path, session, meta, model_id, wire.n_nodes, len(data), spec, heads)
    if warm_up:
        model.warm_up(budget_fraction=decision_budget)
    return model
