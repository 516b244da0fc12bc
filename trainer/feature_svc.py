"""One classifier over any mix of feature families, standardised, with an SVM head; one ONNX graph.

Families (``trainer.features``): ``bow`` (the paper's derivative-window histogram, one per pad),
``stats`` (per-pad level statistics), ``rocket`` (MiniRocket-style PPV of per-pad signals), ``hand``
(the paper's hand-designed baseline features), ``image`` (each taxel's mean over the window: the
contact shape). Their features are concatenated in the order given,
standardised (StandardScaler on the training cases: families differ in scale) and fed to an SVC
whose C (and gamma) come from the same cross-validated search as BowSVC. ``feature_weighting``
(``trainer.feature_weighting``; off by default) reweighs the standardised features in the distance.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.utils.validation import check_is_fitted

from trainer.bow import BagOfWords, as_cases, check_case_shape
from trainer.classifier import SVMHead, check_training_data
from trainer.defaults import DEFAULT_MODEL
from trainer.feature_weighting import check_feature_weighting, feature_weights

__all__ = ["FAMILIES", "FeatureSVC"]

FAMILIES = ("bow", "stats", "rocket", "hand", "image")


class FeatureSVC(SVMHead, ClassifierMixin, BaseEstimator):
    """Feature families + StandardScaler + SVC (one-vs-one), on ``(n_cases, n_channels, n_timepoints)``.

    ``pad_sizes``: channels per pad in channel order (None: one pad); ``pad_shapes``: their
    ``(rows, cols)`` (default: SDH-2 pads, 6 taxels wide). ``n_words``/``window``: the BoW family;
    ``dilations``/``n_biases``: the rocket family. ``feature_weighting``: None (one StandardScaler over
    all features) or a rule of ``trainer.feature_weighting`` (weights folded into the scaler).
    ``c_grid``: the candidate C of the search (None: ``trainer.classifier.C_GRID``).

    Fitted: ``blocks_`` (fitted families, in order), ``bow_`` (the BagOfWords when ``bow`` is a
    family, else absent), ``bow_slice_``, ``scaler_``, ``svm_``, ``classes_``, ``best_params_``,
    ``n_channels_``, ``n_timepoints_``, ``n_features_in_``.
    """

    def __init__(self, families: Sequence[str] = DEFAULT_MODEL["families"], pad_sizes: Sequence[int] | None = None,
                 pad_shapes=None, kernel: str = DEFAULT_MODEL["kernel"], C: float | None = None, gamma: float | str | None = None,
                 n_words: int = DEFAULT_MODEL["K"], window: int = DEFAULT_MODEL["W"], dilations=(1, 2), n_biases: int = 1, random_state=0,
                 fullscale: float = 4095.0, feature_weighting: str | None = None, c_grid: tuple[float, ...] | None = None):
        self.families = families
        self.pad_sizes = pad_sizes
        self.pad_shapes = pad_shapes
        self.kernel = kernel
        self.C = C
        self.gamma = gamma
        self.n_words = n_words
        self.window = window
        self.dilations = dilations
        self.n_biases = n_biases
        self.random_state = random_state
        self.fullscale = fullscale
        self.feature_weighting = feature_weighting
        self.c_grid = c_grid

    def _family(self, name: str):
        from trainer.features import ContactImage, HandGraphFeatures, PadStats, RandomConvPPV

        sizes = None if self.pad_sizes is None else tuple(int(s) for s in self.pad_sizes)
        if name == "bow":
            return BagOfWords(n_words=self.n_words, window=self.window, per_pad=sizes is not None, pad_sizes=sizes,
                              random_state=self.random_state, fullscale=self.fullscale)
        if name == "stats":
            return PadStats(pad_sizes=sizes, pad_shapes=self.pad_shapes, fullscale=self.fullscale)
        if name == "rocket":
            return RandomConvPPV(dilations=self.dilations, n_biases=self.n_biases, random_state=self.random_state,
                                 pad_sizes=sizes, pad_shapes=self.pad_shapes, fullscale=self.fullscale)
        if name == "hand":
            return HandGraphFeatures(pad_sizes=sizes, pad_shapes=self.pad_shapes)
        if name == "image":
            return ContactImage(pad_sizes=sizes, pad_shapes=self.pad_shapes, fullscale=self.fullscale)
        raise ValueError(f"unknown feature family {name!r}; choose from {', '.join(FAMILIES)}")

    def fit(self, X, y, features: np.ndarray | None = None):
        """``features``: ``case_features(X)`` computed before (not None only for such families): the
        families are fitted on the layout and the SVM on these features, as they would be computed."""
        X, y, self.classes_ = check_training_data(self, X, y)
        names = self._names()
        check_feature_weighting(self.feature_weighting)
        _, self.n_channels_, self.n_timepoints_ = X.shape
        self.n_features_in_ = self.n_channels_ * self.n_timepoints_
        if features is not None and not self._per_case():
            raise ValueError(f"features given, but the families {names} learn from the training cases")
        fit_on = (X, y) if features is None else (X[:1], y[:1])  # per-case families learn the layout alone
        self.blocks_ = [(name, self._family(name).fit(*fit_on)) for name in names]
        start = 0
        for name, block in self.blocks_:
            if name == "bow":
                self.bow_ = block
                self.bow_slice_ = slice(start, start + block.n_features_out_)
            start += block.n_features_out_
        sizes = [block.n_features_out_ for _, block in self.blocks_]
        self._fit_scaled_svm(self.transform_histograms(X) if features is None else features, y,
                             weigh=lambda scaled: feature_weights(scaled, sizes, self.feature_weighting))
        return self

    def _names(self) -> tuple[str, ...]:
        names = tuple(self.families)
        if not names or len(set(names)) != len(names):
            raise ValueError(f"families must be distinct names from {FAMILIES}, got {self.families!r}")
        return names

    def _per_case(self) -> bool:
        return not any(getattr(self._family(name), "learns_from_cases", True) for name in self._names())

    def case_features(self, X) -> np.ndarray | None:
        """Each case's features (``transform_histograms``) when they depend on that case alone (no family
        learns from training cases, e.g. no codebook), else None: then features computed once serve the
        fit and the answers of any subset of ``X`` (``trainer.early.Fits``: many subsets of one data set)."""
        if not self._per_case():
            return None
        X = as_cases(X)
        return np.concatenate([self._family(name).fit(X[:1]).transform(X) for name in self._names()], axis=1)

    def transform_histograms(self, X) -> np.ndarray:
        """The concatenated features before scaling (the graph's ``histogram`` tensor)."""
        check_is_fitted(self, "blocks_")
        X = check_case_shape(self, X)
        return np.concatenate([block.transform(X) for _, block in self.blocks_], axis=1)

    def svm_input(self, hist: np.ndarray) -> np.ndarray:
        return self.scaler_.transform(hist)

    def feature_error_bounds(self, X) -> np.ndarray:
        """Bound on |float32 graph - float64| per feature; the BoW block's words are judged window by
        window instead (``handover verify``), so its bound here is zero."""
        parts = [np.zeros((len(X), block.n_features_out_)) if name == "bow" else block.error_bounds(X)
                 for name, block in self.blocks_]
        return np.concatenate(parts, axis=1)

    def onnx_features(self, g, frames: str, output: str):
        """ONNX nodes of every family on ``frames`` ``[N, T, C]``, joined by one Concat into ``output``
        in the families' own layouts (``trainer.features.base.OnnxParts``: the exporter lays the SVM's
        constants out to match, so no node reorders features); a tensor two families share is joined once."""
        from trainer.features.base import OnnxParts, join_parts
        from trainer.features.pad_series import SeriesNeed, pad_series_nodes
        from trainer.onnx_export import features_nodes

        blocks = dict(self.blocks_)
        series_of = blocks.get("hand", blocks.get("stats"))
        if series_of is not None:  # the series hand and stats share, built once with what both need
            stats = blocks.get("stats")
            pad_series_nodes(g, frames, series_of.shapes_, int(series_of.n_timepoints_),
                             SeriesNeed("hand" in blocks, None if stats is None else float(stats.fullscale)))
        every = []
        for name, block in self.blocks_:
            if name == "bow":
                every.append(OnnxParts.in_order([features_nodes(g, frames, block, output=g.name("bow_histogram"))],
                                                block.n_features_out_))
            else:
                every.append(block.onnx_parts(g, frames))
        joined = join_parts(every)
        g.op("Concat", joined.tensors, outputs=[output], axis=1)
        return OnnxParts([output], joined.columns, joined.width, joined.scales)

    def describe(self) -> dict:
        """What the model file's metadata says about the features."""
        check_is_fitted(self, "blocks_")
        out = {"families": [name for name, _ in self.blocks_],
               "n_features": int(sum(b.n_features_out_ for _, b in self.blocks_)), "scale_features": True}
        if self.feature_weighting is not None:
            out["feature_weighting"] = self.feature_weighting
        if hasattr(self, "bow_"):
            out.update(windows=[int(w) for w, _, _ in self.bow_.scales()], n_words=int(self.bow_.n_words),
                       feature_groups=[int(s) for s in self.bow_.pad_sizes_])
        if any(name == "rocket" for name, _ in self.blocks_):
            out.update(dilations=[int(d) for d in np.atleast_1d(self.dilations)], n_biases=int(self.n_biases))
        return out

