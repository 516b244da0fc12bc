"""The model loader: reads a file, checks the contract (runtime.model_meta) and opens it to run.

It needs onnxruntime only: metadata comes from ``session.get_modelmeta()``, operator domains and
external-data references from a small protobuf wire reader (``runtime.onnx_wire``), so the robot
PC never installs ``onnx``. A loaded model is warmed up before it serves (``LoadedModel.warm_up``).
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import threading
import time
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from firmware_io.errors import HandoverError
from runtime.early import EarlySpec, head_outputs
from runtime.health import one_line
from runtime.model_meta import (
    ALLOWED_DOMAINS,
    CODEWORD_KERNEL,
    DEFAULT_MAX_BYTES,
    INPUT_NAME,
    METADATA_KEY,
    OUTPUT_NAMES,
    SCHEMA_VERSION,
    ModelContractError,
    ModelMeta,
    ModelUnreadableError,
    check_bow_params,
    check_io,
    early_spec,
    optional_table,
    other_file_kind,
)
from runtime.onnx_wire import WireError, keep_outputs, summarize
from runtime.output_check import DEFAULT_BUDGET_FRACTION, probe, probe_windows

__all__ = [
    "CODEWORD_KERNEL", "INPUT_NAME", "METADATA_KEY", "OUTPUT_NAMES", "SCHEMA_VERSION", "LoadedModel",
    "ModelContractError", "ModelInputError", "ModelMeta", "ModelUnreadableError", "load_model", "optional_table",
    "session_options"
]

WRITE_AGAIN = "copy it again from where it was trained, or train it again (handover train writes report/model.onnx)"
"""What to do about a model file that is not a whole ONNX model: its bytes are lost, only a copy helps."""

WARM_UP_BOUND_S = 10.0
"""Longest a model's whole warm-up may take (a few dozen decisions; the slowest model a budget lets
through takes well under a second)."""


class DecisionEnded(HandoverError, RuntimeError):
    """A decision was ended from outside (``LoadedModel.end_decision``): the model ran too long."""


class ModelInputError(HandoverError, ValueError):
    """Input frames the model refuses (wrong shape, non-finite values)."""



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
        self.early_note: str | None = None
        """Why the warm-up disabled early heads the file carries (``_drop_blind_heads``), or None."""

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
        """``run`` without ``check_input``, for the hot path's windows (float32 copies of uint16 frames: finite,
        right shape by construction; onnxruntime still refuses a wrong dtype or shape).

        One ``[1, T, C]`` window is first copied to a 64-byte aligned array: onnxruntime's summation order
        depends on the input's alignment, so this way one window gives one answer, bit for bit, wherever the
        ring holds it (a replay and the service agree).
        """
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
        self._drop_blind_heads()

    def _drop_blind_heads(self) -> None:
        """An early head decides an event alone, so one that cannot tell windows apart (the same class,
        with the certainty to report, on every warm-up window where the full model gives more than one)
        is disabled: a head that always said bump against a full model that says pull decided every event
        after a few frames. Disagreeing on some of these synthetic windows is no fault: a head sees only
        their first frames, and on a hand with other gains (lab B) an honest 4-frame head differed on 5 of 7.
        Only answers the rule could report count: a dormant one, or one of a class training keeps to T, decides
        no event (a stream model's 4-frame head is sure of dormant on most of these windows).
        The full model still serves and ``early_note`` says why."""
        if self.early is None:
            return
        meta = self.meta
        windows = probe_windows(meta.T, meta.n_channels, meta.fullscale)
        full = self.run_trusted(windows)[0]
        spec, keep, against = self.early, [], []
        need = spec.needs(meta.classes, meta.dormant_class)
        for index in range(len(spec.points)):
            labels, scores = self.run_head(index, windows)
            sure = [spec.confidence(index, row, int(label)) >= need[int(label)]
                    for label, row in zip(labels, scores, strict=True)]
            blind = all(sure) and len(set(labels.tolist())) == 1 and set(full.tolist()) != set(labels.tolist())
            (against if blind else keep).append(index)
        if not against:
            return
        self.early_note = (f"model {self.model_id}: early heads at {', '.join(str(spec.points[i]) for i in against)} "
                           f"frames disabled: they report one class with the certainty to report on every one of "
                           f"{len(windows)} warm-up windows, where the full model's answers differ; the full model "
                           "decides those events")
        self._head_sessions = [self._head_sessions[i] for i in keep]
        self._head_outputs = [self._head_outputs[i] for i in keep]
        self.early = replace(spec, points=tuple(spec.points[i] for i in keep),
                             calibration=tuple(spec.calibration[i] for i in keep)) if keep else None


def _aligned(shape: tuple[int, ...]) -> np.ndarray:
    """float32 zeros of ``shape`` starting on a 64-byte boundary."""
    n = int(np.prod(shape))
    raw = np.zeros(n + 16, dtype=np.float32)
    start = (-raw.ctypes.data % 64) // 4
    return raw[start : start + n].reshape(shape)


def _read_regular(path: Path, where: str, max_bytes: int) -> bytes:
    """At most ``max_bytes + 1`` bytes of a regular file. Opened without blocking and checked by its own
    descriptor: a FIFO would wait for a writer forever and a device (/dev/zero) has no size to trust."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            inside = sorted(p.name for p in path.glob("*.onnx"))[:3]
            raise ModelContractError(f"{where}: a folder, not a model file; give the .onnx file"
                                     + (f" in it ({', '.join(inside)})" if inside else ""))
        if not stat.S_ISREG(st.st_mode):
            raise ModelContractError(f"{where}: not a regular file (a device, FIFO or socket); give the .onnx file "
                                     "handover train wrote")
        if st.st_size > max_bytes:
            raise ModelContractError(f"{where}: {st.st_size} bytes exceeds the limit of {max_bytes}")
        with os.fdopen(os.dup(fd), "rb") as fh:
            return fh.read(max_bytes + 1)
    finally:
        os.close(fd)


def _read(path: Path, max_bytes: int) -> tuple[bytes, Any]:
    """The file's bytes and wire summary, refused before onnxruntime sees them (too big, empty, not
    ONNX, external data, NaN constants, foreign operators)."""
    where = f"model {path}"
    try:
        data = _read_regular(path, where, max_bytes)
    except OSError as exc:
        raise ModelContractError(f"{where}: cannot read ({exc.strerror or exc}); check the path and that this user "
                                 "may read the file") from exc
    if len(data) > max_bytes:
        raise ModelContractError(f"{where}: {len(data)} bytes exceeds the limit of {max_bytes}")
    if not data:
        raise ModelUnreadableError(f"{where}: empty file; {WRITE_AGAIN}")
    try:
        wire = summarize(data)
    except WireError as exc:
        other = other_file_kind(data)
        if other:
            raise ModelUnreadableError(f"{where}: this is {other}; give a .onnx model") from exc
        raise ModelUnreadableError(f"{where}: not an ONNX model or truncated ({exc}); {WRITE_AGAIN}") from exc
    if wire.external_data:
        raise ModelContractError(f"{where}: references external data; a model must be one self-contained file")
    if wire.nan_initializers:
        names = ", ".join(wire.nan_initializers[:3]) + (" ..." if len(wire.nan_initializers) > 3 else "")
        raise ModelContractError(f"{where}: constant(s) {names} hold NaN (a damaged file or a model fitted on "
                                 "NaN); export it again from its .joblib or train it again")
    foreign = sorted((wire.opset_domains | wire.node_domains) - ALLOWED_DOMAINS)
    if foreign:
        raise ModelContractError(f"{where}: uses non-standard operator domain(s) {foreign}; allowed: ai.onnx, ai.onnx.ml")
    return data, wire


def _session(data: bytes, options: Any) -> Any:
    """One CPU session; ``enable_fallback=0``: on a failure onnxruntime's Python wrapper would otherwise
    print an "EP Error" banner with print(), i.e. into the daemon's stdout event stream."""
    import onnxruntime as ort

    return ort.InferenceSession(data, sess_options=options, providers=["CPUExecutionProvider"], enable_fallback=0)


def _meta(session: Any, wire: Any, where: str) -> tuple[ModelMeta, EarlySpec | None]:
    """The metadata the graph carries, checked against the graph."""
    try:
        raw = session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
    except UnicodeDecodeError as exc:  # onnxruntime decodes metadata strings as UTF-8 for Python
        raise ModelContractError(f"{where}: metadata is not valid UTF-8 (byte {exc.start}); damaged file?") from None
    if raw is None:
        raise ModelUnreadableError(f"{where}: no {METADATA_KEY!r} metadata (not a handover model)")
    try:
        meta = ModelMeta.from_dict(json.loads(raw))
        spec = early_spec(meta)
        check_io(session, meta, spec)
        check_bow_params(meta, wire.initializer_dims)
    except json.JSONDecodeError as exc:
        raise ModelContractError(f"{where}: metadata is not valid JSON ({exc.msg} at {exc.pos})") from exc
    except RecursionError:
        raise ModelContractError(f"{where}: metadata is nested too deeply") from None
    except ModelContractError as exc:
        raise ModelContractError(f"{where}: {exc}") from exc
    except UnicodeDecodeError as exc:  # input/output names of a damaged file
        raise ModelContractError(f"{where}: a name in the graph is not valid UTF-8 (byte {exc.start}); damaged file?") from None
    return meta, spec


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
    path = Path(path)
    where = f"model {path}"
    data, wire = _read(path, max_bytes)
    options = session_options(intra_op_threads, allow_spinning)
    try:
        session = _session(data, options)
    except Exception as exc:  # onnxruntime raises several unrelated types for a bad graph
        raise ModelUnreadableError(f"{where}: onnxruntime cannot load it: {one_line(exc)}") from exc
    meta, spec = _meta(session, wire, where)
    heads: list = []
    if spec is not None:  # one session per head: onnxruntime runs every node of a graph
        parts = [OUTPUT_NAMES, *(head_outputs(p) for p in spec.points)]
        try:
            session, *heads = (_session(keep_outputs(data, names), options) for names in parts)
        except Exception as exc:  # a damaged graph whose parts do not stand alone
            raise ModelContractError(f"{where}: its early heads do not load on their own: {one_line(exc)}") from exc
    model_id = hashlib.sha256(data).hexdigest()[:12]
    model = LoadedModel(path, session, meta, model_id, wire.n_nodes, len(data), spec, heads)
    if warm_up:
        model.warm_up(budget_fraction=decision_budget)
    return model
