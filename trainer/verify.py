"""Compare an exported graph with the float64 reference on the same windows.

The reference is the scikit-learn model the graph was exported from (``model.joblib``, its sha256 in
the ONNX metadata), run in float64. The graph runs with its histogram and per-window word choices
exposed, so every label disagreement traces to word choices or an SVM decision, each with its margin
in units of the float32 error bound (``trainer.numerics``). A differing word is excused only as a near
tie of that window; a histogram or label difference only when explained by near ties.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from firmware_io.errors import HandoverError
from trainer.numerics import SAFETY, reference

__all__ = [
    "BATCH", "GraphRunner", "VerifyError", "VerifyReport", "check_nonfinite_refused", "compare", "load_reference"
]

BATCH = 64
"""Windows per run of graph and reference: the float64 reference holds ~20 MB per batch of 64."""
HIST_TOLERANCE = 1e-6
"""Histogram entries are counts / windows in [0, 1]; float32 division is within 6e-8 of float64."""


class VerifyError(HandoverError, ValueError):
    """A model, reference or data set that cannot be verified; the message says why."""


@dataclass
class Disagreement:
    case: int
    source: str
    graph_label: str
    reference_label: str
    codeword_margin: float
    """Smallest relative codeword margin over the case's active windows (near tie < SAFETY)."""
    codeword_gap: float
    """Smallest absolute gap between the two nearest squared distances (float64)."""
    svm_margin: float
    """min over pairs of |decision| / float32 bound (near tie < SAFETY)."""
    hist_max_abs_diff: float
    near_tie: bool
    reason: str


@dataclass
class VerifyReport:
    n_cases: int = 0
    agreement: float = 1.0
    disagreements: list[Disagreement] = field(default_factory=list)
    near_tie_disagreements: int = 0
    unexplained_disagreements: int = 0
    max_score_abs_diff: float = 0.0
    max_score_abs_diff_same_votes: float = 0.0
    """Over cases whose histogram and votes agree (no tie involved)."""
    max_hist_abs_diff: float = 0.0
    hist_mismatch_cases: int = 0
    hist_mismatch_unexplained: int = 0
    near_tie_cases: int = 0
    """Cases with a codeword or SVM near tie, whatever the outcome: float32 cannot certify their
    vote by the worst-case bound, they are not disagreements."""
    svm_near_tie_cases: int = 0
    """Of those, cases whose SVM decision is the near tie (large dual coefficients amplify rounding)."""
    features: str = "histogram"
    """What the graph's feature tensor is: ``histogram`` (BoW alone) or ``feature vector`` (families)."""
    codebook: bool = True
    """The model has the BoW family: its windows pick codewords (nothing to say about them otherwise)."""
    window_word_mismatches: int = 0
    """Active windows whose graph word differs from the float64 word."""
    window_word_mismatches_near_tie: int = 0
    window_word_mismatches_unexplained: int = 0
    """Differing windows with a margin of at least SAFETY x bound: never a rounding effect."""
    nan_or_inf_outputs: int = 0
    nonfinite_input_refused: bool | None = None
    by_source: dict = field(default_factory=dict)
    safety: float = SAFETY

    def to_dict(self) -> dict:
        d = asdict(self)
        d["disagreements"] = [asdict(x) for x in self.disagreements]
        return d

    @property
    def ok(self) -> bool:
        return (self.unexplained_disagreements == 0 and self.nan_or_inf_outputs == 0
                and self.hist_mismatch_unexplained == 0 and self.window_word_mismatches_unexplained == 0)


class GraphRunner:
    """The exported graph with its histogram and per-window words as extra outputs (single thread,
    like the daemon). ``word_outputs``: the ArgMin tensors ``[N, S, C]``, one per hard scale, in
    feature order."""

    def __init__(self, onnx_path: str | Path):
        import onnx
        import onnxruntime as ort

        from runtime.model import session_options
        from trainer.onnx_export import HISTOGRAM, feature_columns, feature_scales

        self.path = Path(onnx_path)
        proto = onnx.load(str(onnx_path))
        if not any(HISTOGRAM in node.output for node in proto.graph.node):
            raise VerifyError(f"{onnx_path}: no {HISTOGRAM!r} tensor in the graph (not exported by this project)")
        try:
            self.columns = feature_columns(proto)  # the graph's own layout of the features, or None
            self.scales = feature_scales(proto)  # and the factor each one carries there, or None
        except ValueError as exc:
            raise VerifyError(f"{onnx_path}: {exc}") from None
        proto.graph.output.append(onnx.helper.make_tensor_value_info(HISTOGRAM, onnx.TensorProto.FLOAT, ["N", "F"]))
        self.word_outputs = [node.output[0] for node in proto.graph.node if node.op_type == "ArgMin"]
        for name in self.word_outputs:
            proto.graph.output.append(onnx.helper.make_tensor_value_info(name, onnx.TensorProto.INT64, ["N", "S", "C"]))
        self.session = ort.InferenceSession(proto.SerializeToString(), session_options(), providers=["CPUExecutionProvider"])

    def run(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        labels, scores, hist = self.session.run(["label", "scores", "histogram"], {"frames": frames})
        return labels, scores, self._in_order(hist)

    def _in_order(self, hist: np.ndarray) -> np.ndarray:
        """The features in the reference's order and units (the graph may hold them in its own layout,
        times constants)."""
        if self.columns is not None:
            if self.columns.size and self.columns.max() >= hist.shape[1]:
                raise VerifyError(f"{self.path}: model property handover_feature_columns points past the graph's "
                                  f"{hist.shape[1]} features (damaged); re-export the model")
            hist = hist[:, self.columns]
        if self.scales is None:
            return hist
        if self.scales.size != hist.shape[1]:
            raise VerifyError(f"{self.path}: model property handover_feature_scales has {self.scales.size} entries "
                              f"for {hist.shape[1]} features (damaged); re-export the model")
        return hist.astype(np.float64) / self.scales

    def run_with_words(self, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
        """Labels, scores, histogram and the word chosen for every window ``[N, S, C]`` per hard scale."""
        out = self.session.run(["label", "scores", "histogram", *self.word_outputs], {"frames": frames})
        return out[0], out[1], self._in_order(out[2]), list(out[3:])


@dataclass
class WindowCheck:
    """Window-by-window comparison of the graph's words with the float64 words, per case."""

    mismatched: np.ndarray
    """Differing active windows per case."""
    unexplained: np.ndarray
    """Differing active windows whose margin is not a near tie, per case."""
    allowance: np.ndarray
    """``(n, F)`` (or ``(n, 1)`` zeros without hard words): how far each histogram entry may move
    through near-tie windows."""


def check_windows(model, frames: np.ndarray, graph_words: list[np.ndarray], fold_derivative: bool = False
                  ) -> WindowCheck:
    """Compare the graph's per-window words with the reference's; no hard words -> nothing to check."""
    from trainer.bow import channel_groups
    from trainer.numerics import window_codewords

    n = len(frames)
    bow = getattr(model, "bow_", None)
    mismatched, unexplained = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    if bow is None or getattr(bow, "assignment", "hard") != "hard":
        return WindowCheck(mismatched, unexplained, np.zeros((n, 1)))  # broadcasts over any feature count
    scales = bow.scales()
    if len(graph_words) != len(scales):
        raise VerifyError(f"the graph has {len(graph_words)} codeword choices (ArgMin) for {len(scales)} codebooks")
    X = np.asarray(frames, dtype=np.float32).astype(np.float64).transpose(0, 2, 1)  # (n, c, T)
    active = np.any(X != 0, axis=2)  # (n, c)
    groups = channel_groups(bow.pad_sizes_)
    indicator = (groups[None, :] == np.arange(len(bow.pad_sizes_))[:, None]).astype(np.float64)  # (G, c)
    parts = []
    for (_, codebook, _), words in zip(scales, graph_words, strict=True):
        best, rel = window_codewords(X, codebook, fold_derivative)  # (n, c, S)
        graph = np.asarray(words).transpose(0, 2, 1)  # [N, S, C] -> (n, c, S)
        if graph.shape != best.shape:
            raise VerifyError(f"graph words have shape {graph.shape}, the reference {best.shape}")
        act = active[:, :, None]
        tie = (rel < SAFETY) & act
        differ = (graph != best) & act
        mismatched += differ.sum(axis=(1, 2))
        unexplained += (differ & ~tie).sum(axis=(1, 2))
        n_windows = best.shape[2]
        ties = tie.sum(axis=2) @ indicator.T  # (n, G) near-tie windows per group
        windows = (active @ indicator.T) * n_windows
        allow = np.where(windows > 0, ties / np.maximum(windows, 1), 0.0)
        parts.append(np.repeat(allow, len(codebook), axis=1))  # group-major, like the histogram
    if getattr(bow, "level_features", False):
        parts.append(np.zeros((n, 2 * len(bow.level_groups_))))
    allowance = np.concatenate(parts, axis=1)
    where = getattr(model, "bow_slice_", None)
    if where is not None:  # FeatureSVC: the histogram is one block of a longer feature vector
        full = np.zeros((n, int(model.scaler_.n_features_in_)))
        full[:, where] = allowance
        allowance = full
    return WindowCheck(mismatched, unexplained, allowance)


def reference_path_for(onnx_path: Path, meta_extra: dict, explicit: str | Path | None) -> Path:
    if explicit is not None:
        return Path(explicit)
    name = (meta_extra.get("reference") or {}).get("file")
    return onnx_path.with_name(name) if name else onnx_path.with_suffix(".joblib")


def load_reference(onnx_path: Path, meta_extra: dict, explicit: str | Path | None = None,
                   frames_shape: tuple[int, int] | None = None):
    """The fitted scikit-learn model behind a graph; refuses a file whose sha256 does not match, or
    (``frames_shape``: the graph's ``(T, C)``) one fitted on windows of another size."""
    from trainer.trained_file import load_trained

    path = reference_path_for(onnx_path, meta_extra, explicit)
    if not path.is_file():
        raise VerifyError(f"reference model {path} not found (keep the .joblib next to the .onnx, or pass --reference)")
    expected = (meta_extra.get("reference") or {}).get("sha256")
    if expected and hashlib.sha256(path.read_bytes()).hexdigest() != expected:
        raise VerifyError(f"reference model {path} is not the one this graph was exported from (sha256 differs)")
    model, _ = load_trained(path)
    fitted = getattr(model, "n_features_in_", None)
    if frames_shape is not None and fitted is not None and fitted != frames_shape[0] * frames_shape[1]:
        raise VerifyError(f"reference model {path} was fitted on windows of {fitted} values, this graph takes "
                          f"{frames_shape[0]} frames x {frames_shape[1]} taxels = {frames_shape[0] * frames_shape[1]}: "
                          "give the .joblib this graph was exported from (--reference)")
    return model


def compare(model, runner: GraphRunner, frames: np.ndarray, sources: list[str], fold_derivative: bool = False,
            report: VerifyReport | None = None) -> VerifyReport:
    """Run graph and reference on ``frames`` float32 ``[N, T, C]``; accumulate into ``report``."""
    report = report or VerifyReport()
    families = [name for name, _ in getattr(model, "blocks_", [("bow", None)])]
    report.features = "histogram" if families == ["bow"] else "feature vector"
    report.codebook = "bow" in families
    classes = [str(c) for c in model.classes_]
    n_done = report.n_cases
    n_agree = round(report.agreement * report.n_cases)
    for start in range(0, len(frames), BATCH):
        batch = np.ascontiguousarray(frames[start : start + BATCH], dtype=np.float32)
        src = sources[start : start + BATCH]
        labels, scores, hist, words = runner.run_with_words(batch)
        ref = reference(model, batch, fold_derivative)
        windows = check_windows(model, batch, words, fold_derivative)
        finite = np.isfinite(scores).all(axis=1) & np.isfinite(hist).all(axis=1)
        report.nan_or_inf_outputs += int((~finite).sum())
        entry_diff = np.abs(hist.astype(np.float64) - ref["hist"])
        hist_diff = entry_diff.max(axis=1)
        # soft words and level features: beyond the tolerance only what their float32 bound allows
        rounding = HIST_TOLERANCE + SAFETY * ref["hist_error"]
        hist_bad = (entry_diff > rounding).any(axis=1)
        # hard words: a histogram may differ only through windows whose word is a near tie, and by
        # at most (near-tie windows / active windows) of the pad group
        words_ok = windows.unexplained == 0
        hist_explained = words_ok & ~(entry_diff > rounding + windows.allowance).any(axis=1)
        report.window_word_mismatches += int(windows.mismatched.sum())
        report.window_word_mismatches_unexplained += int(windows.unexplained.sum())
        report.window_word_mismatches_near_tie += int((windows.mismatched - windows.unexplained).sum())
        score_diff = np.abs(scores.astype(np.float64) - ref["scores"]).max(axis=1)
        same_votes = np.floor(scores + 0.5) == np.floor(ref["scores"] + 0.5)
        svm_margin = (np.abs(ref["decisions"]) / np.maximum(ref["decision_bounds"], 1e-300)).min(axis=1)
        cw_margin = ref["codeword_margin"]
        cw_tie, svm_tie = cw_margin < SAFETY, svm_margin < SAFETY
        report.max_score_abs_diff = max(report.max_score_abs_diff, float(np.nanmax(score_diff, initial=0.0)))
        keep = same_votes.all(axis=1) & ~hist_bad
        report.max_score_abs_diff_same_votes = max(
            report.max_score_abs_diff_same_votes, float(np.nanmax(score_diff[keep], initial=0.0))
        )
        report.max_hist_abs_diff = max(report.max_hist_abs_diff, float(np.nanmax(hist_diff, initial=0.0)))
        report.hist_mismatch_cases += int(hist_bad.sum())
        report.hist_mismatch_unexplained += int((hist_bad & ~hist_explained).sum())
        report.near_tie_cases += int((cw_tie | svm_tie).sum())
        report.svm_near_tie_cases += int(svm_tie.sum())
        agree = labels == ref["labels"]
        n_agree += int(agree.sum())
        for i in np.flatnonzero(~agree):
            if hist_bad[i] or not words_ok[i]:
                near, reason = bool(hist_explained[i] and cw_tie[i]), "codeword choice (histogram differs)"
                if windows.unexplained[i]:
                    reason += f", {int(windows.unexplained[i])} window(s) with a different word beyond the bound"
            else:
                near, reason = bool(svm_tie[i]), "SVM decision (same histogram)"
            report.disagreements.append(
                Disagreement(
                    case=n_done + start + int(i),
                    source=src[i],
                    graph_label=classes[int(labels[i])],
                    reference_label=classes[int(ref["labels"][i])],
                    codeword_margin=float(cw_margin[i]),
                    codeword_gap=float(ref["codeword_gap"][i]),
                    svm_margin=float(svm_margin[i]),
                    hist_max_abs_diff=float(hist_diff[i]),
                    near_tie=near,
                    reason=reason + ("" if near else ": NOT a near tie"),
                )
            )
            report.near_tie_disagreements += int(near)
            report.unexplained_disagreements += int(not near)
        for s, a in zip(src, agree, strict=True):
            entry = report.by_source.setdefault(s, {"n_cases": 0, "agree": 0})
            entry["n_cases"] += 1
            entry["agree"] += int(a)
    report.n_cases = n_done + len(frames)
    report.agreement = n_agree / report.n_cases if report.n_cases else 1.0
    return report


def check_nonfinite_refused(onnx_path: Path) -> bool:
    """True when the runtime loader refuses NaN and infinity in the input frames."""
    from runtime.model import ModelInputError, load_model

    model = load_model(onnx_path)
    shape = (1, model.meta.T, model.meta.n_channels)
    refused = 0
    for bad in (np.nan, np.inf, -np.inf):
        x = np.zeros(shape, dtype=np.float32)
        x[0, -1, 0] = bad
        try:
            model.run(x)
        except ModelInputError:
            refused += 1
    return refused == 3
