"""The paper's classifier: Bag-of-Words histograms fed to a one-vs-one SVM.

The paper trains a hard-margin SVM (Gaussian kernel). ``C`` or ``gamma`` left None is chosen by a small
stratified cross-validated grid search on the training histograms only; the grid reaches C = 1e6, so
a (practically) hard margin can win. Whether the fit *is* hard-margin is a fact of the fit, counted by
``margin_report``; the chosen values are in ``best_params_``.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.exceptions import ConvergenceWarning
from sklearn.model_selection import GridSearchCV, StratifiedKFold
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils.validation import assert_all_finite, check_is_fitted, column_or_1d

from trainer.bow import BagOfWords, as_cases
from trainer.defaults import PAPER_MODEL

__all__ = ["C_GRID", "MAX_ITER", "BowSVC", "SVMHead", "check_training_data", "converged", "margin_report", "svc"]

C_GRID = (1e6, 1e4, 1000.0, 100.0, 10.0, 1.0)
"""Candidate C, largest first, up to 1e6 (a hard margin in practice when the training cases are
separable); on equal cross-validated scores the search keeps the first, i.e. the harder margin."""

AT_BOUND_RTOL = 1e-6
"""libsvm sets a dual coefficient at the bound to exactly C; the tolerance only absorbs rounding."""

GAMMA_FACTORS = (0.1, 1.0, 10.0)
"""Candidate gamma as multiples of scikit-learn's "scale" value 1 / (n_features * var(H))."""

DEFAULT_C = 100.0
"""Used when a search is impossible (a class with a single training case)."""

CV_FOLDS = 3

MAX_ITER = 1_000_000
"""libsvm iterations (per one-vs-one problem) any SVC of the trainer may take. scikit-learn's default is no
limit, and at a large C on cases that are not separable libsvm can take millions (minutes a fit); the
product's trainings converge in far fewer, so their models are unchanged (results/svm_max_iter.md)."""


def svc(kernel: str, **params) -> SVC:
    """Every SVC of the trainer (searched and final fits): one-vs-one, "ovr" scores, at most MAX_ITER iterations."""
    return SVC(kernel=kernel, decision_function_shape="ovr", max_iter=MAX_ITER, **params)


def converged(svm: SVC) -> bool:
    """False when libsvm stopped at the iteration cap in some one-vs-one problem (not the SVM of its C)."""
    return svm.max_iter < 0 or int(np.max(svm.n_iter_)) < svm.max_iter


def _converged_score(estimator, X, y) -> float:
    return float(converged(estimator))


def _params_text(params: dict) -> str:
    return " ".join(f"{k}={v:.3g}" for k, v in params.items() if isinstance(v, float))


def check_training_data(estimator, X, y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The checks every classifier here makes in ``fit``: cases, labels, kernel; returns X, y, classes."""
    if estimator.kernel not in ("rbf", "linear"):
        raise ValueError(f"kernel must be 'rbf' or 'linear', got {estimator.kernel!r}")
    if y is None:
        raise ValueError(f"{type(estimator).__name__} requires y to be passed, but the target y is None")
    X = as_cases(X)
    if X.shape[2] < 2:
        raise ValueError(f"cases need at least 2 frames (the features read how pressure changes), got "
                         f"{X.shape[2]} frame ({X.shape[2]} feature(s) per channel)")
    y = column_or_1d(y, warn=True)
    if y.dtype.kind in "fc":  # NaN/inf labels: refuse before type_of_target casts them (RuntimeWarning)
        assert_all_finite(y, input_name="y")
    if len(y) != len(X):
        raise ValueError(f"y has {len(y)} labels for {len(X)} cases")
    check_classification_targets(y)
    classes = np.unique(y)
    if len(classes) < 2:
        raise ValueError(f"need samples of at least 2 classes, got 1 class ({classes[0]!r})")
    return X, y, classes


def choose_svm_params(features: np.ndarray, y: np.ndarray, kernel: str, C=None, gamma=None,
                      c_grid: tuple[float, ...] | None = None) -> tuple[dict, str | None]:
    """C (and gamma for rbf) by a stratified 3-fold grid search on these training features only, and a line
    naming the candidates that did not converge (``_best_candidate``), else None.

    Given values are kept; the grid covers only what is None (C from ``c_grid``, default ``C_GRID``).
    With a class of one case no search is possible and DEFAULT_C / sklearn's "scale" gamma are used.
    """
    scale = 1.0 / (features.shape[1] * max(float(features.var()), 1e-12))
    fixed: dict = {}
    grid: dict = {}
    if C is None:
        grid["C"] = list(c_grid or C_GRID)
    else:
        fixed["C"] = float(C)
    if kernel == "rbf":
        if gamma is None:
            grid["gamma"] = [scale * f for f in GAMMA_FACTORS]
        else:
            fixed["gamma"] = gamma
    if not grid:
        return fixed, None
    _, counts = np.unique(y, return_counts=True)
    n_splits = min(CV_FOLDS, int(counts.min()))
    if n_splits < 2:
        defaults = {"C": DEFAULT_C, "gamma": scale} if kernel == "rbf" else {"C": DEFAULT_C}
        return {**defaults, **fixed}, None
    cv = StratifiedKFold(n_splits=n_splits, shuffle=True, random_state=0)
    # refit=False: the caller fits the final SVC itself (a refit here was one more fit on every case, unused)
    search = GridSearchCV(svc(kernel, **fixed), grid, cv=cv, n_jobs=1, refit=False,
                          scoring={"accuracy": "accuracy", "converged": _converged_score})
    with warnings.catch_warnings():  # a capped fit is counted by its candidate and said once, below
        warnings.simplefilter("ignore", ConvergenceWarning)
        search.fit(features, y)
    return _best_candidate(search.cv_results_, fixed)


def _best_candidate(results: dict, fixed: dict) -> tuple[dict, str | None]:
    """The candidate converged in the most folds, then of best mean accuracy, then the first (the harder margin).

    A fit stopped at MAX_ITER is not the SVM of its C, so its score does not measure that C; and the
    unconverged ones are the large C, first in the grid, which win ties. So they rank below every
    candidate that converged and one line says which they were (they win only if none converged).
    """
    done, accuracy = results["mean_test_converged"], results["mean_test_accuracy"]
    best = max(range(len(done)), key=lambda i: (done[i], accuracy[i]))
    chosen = {**fixed, **{k: float(v) for k, v in results["params"][best].items()}}
    capped = [_params_text(p) for p, d in zip(results["params"], done, strict=True) if d < 1.0]
    note = None if not capped else (
        f"SVM search: {len(capped)} of {len(done)} candidates stopped at {MAX_ITER} libsvm iterations without "
        f"converging in some fold ({', '.join(capped)}) and ranked below the converged ones; chose {_params_text(chosen)}")
    return chosen, note


def fit_svc(features: np.ndarray, y: np.ndarray, kernel: str, params: dict) -> tuple[SVC, str | None]:
    """The final SVC on all cases, and a line when it stopped at MAX_ITER (an approximate solution)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        svm = svc(kernel, **params).fit(features, y)
    return svm, None if converged(svm) else (
        f"SVM fit ({_params_text(params)}) stopped at {MAX_ITER} libsvm iterations without converging: the model is "
        "an approximate solution (a smaller C converges sooner)")


def margin_report(svm) -> dict:
    """How hard the fitted SVM's margin is: C, support vectors, and how many sit at the bound C.

    A support vector at the bound (|dual coefficient| = C in some one-vs-one problem) is a
    training case inside the margin or misclassified: the margin is soft there. ``hard_margin``
    is True only when none is at the bound (then the constraint alpha <= C is inactive and the
    solution is the same for any larger C, i.e. the hard-margin SVM).
    """
    C = float(svm.C)
    dual = np.abs(np.asarray(svm.dual_coef_, dtype=np.float64))
    at_bound = np.any(dual >= C * (1.0 - AT_BOUND_RTOL), axis=0)
    n_sv, n_bound = int(dual.shape[1]), int(at_bound.sum())
    hard = n_bound == 0
    statement = (
        f"hard margin: no support vector at the bound C={C:g} (any larger C gives the same SVM)"
        if hard else
        f"soft margin, not the paper's hard margin: {n_bound} of {n_sv} support vectors "
        f"({100.0 * n_bound / max(n_sv, 1):.0f} %) sit at the bound C={C:g} (inside the margin or misclassified)"
    )
    return {"C": C, "n_support_vectors": n_sv, "n_at_bound": n_bound,
            "share_at_bound": n_bound / n_sv if n_sv else 0.0, "hard_margin": hard, "statement": statement}


class SVMHead:
    """The output side every classifier here shares: features -> ``svm_input`` -> one-vs-one SVC.

    Subclasses provide ``transform_histograms(X)`` (the graph's feature tensor) and ``svm_input``.
    """

    def _fit_scaled_svm(self, features: np.ndarray, y: np.ndarray, weigh=None) -> None:
        """Standardise the features, choose C/gamma, fit the SVC: ``scaler_``, ``best_params_``, ``svm_``.
        ``weigh`` (standardised features -> a weight per feature) is folded into the scaler's ``scale_``."""
        self.scaler_ = StandardScaler().fit(features)
        if weigh is not None:
            self.scaler_.scale_ = self.scaler_.scale_ / weigh(self.scaler_.transform(features))
        self._fit_svm(self.scaler_.transform(features), y)

    def _fit_svm(self, features: np.ndarray, y: np.ndarray) -> None:
        """Choose C/gamma and fit the SVC: ``best_params_``, ``svm_``, and ``svm_notes_``: a line for each fit
        that stopped at MAX_ITER (none when all converged), for the report. Only a capped final fit is raised
        as a ConvergenceWarning: candidates the search ranked last for it leave the model as good as ever."""
        self.best_params_, search_note = choose_svm_params(features, y, self.kernel, self.C, self.gamma,
                                                           getattr(self, "c_grid", None))
        self.svm_, fit_note = fit_svc(features, y, self.kernel, self.best_params_)
        self.svm_notes_ = [note for note in (search_note, fit_note) if note]
        if fit_note:
            warnings.warn(fit_note, ConvergenceWarning, stacklevel=3)

    def decision_function(self, X) -> np.ndarray:
        """sklearn-style one-vs-rest scores of the SVC (ovo votes + bounded confidences)."""
        features = self.svm_input(self.transform_histograms(X))  # first: it raises NotFittedError
        return self.svm_.decision_function(features)

    def predict(self, X) -> np.ndarray:
        """Class labels, decided by one-vs-one votes (ties -> the class listed first)."""
        features = self.svm_input(self.transform_histograms(X))
        return self.svm_.predict(features)

    def scores_and_labels(self, X, features: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``decision_function(X)`` and ``predict(X)`` from one pass of the features (``features``: those of
        ``X``, computed before)."""
        features = self.svm_input(self.transform_histograms(X) if features is None else features)
        return self.svm_.decision_function(features), self.svm_.predict(features)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.three_d_array = True
        return tags


class BowSVC(SVMHead, ClassifierMixin, BaseEstimator):
    """BagOfWords (K words, window W, derivative, active series) + SVC (one-vs-one).

    The options beyond the paper (``window`` as a sequence, ``assignment``, ``temperature``,
    ``level_features``, ``max_windows``, ``fullscale``) are BagOfWords's; ``scale_features=True`` standardises the features
    (StandardScaler, fitted on the training cases) before the SVM, which matters when histogram
    entries and level features of different spread are mixed.

    Fitted: ``bow_`` (BagOfWords), ``scaler_`` (StandardScaler or None), ``svm_`` (sklearn SVC),
    ``classes_``, ``best_params_`` ({"C": ..., "gamma": ...} as used), ``n_features_in_``.
    """

    def __init__(
        self,
        n_words: int = PAPER_MODEL["K"],
        window: int = PAPER_MODEL["W"],
        kernel: str = PAPER_MODEL["kernel"],
        C: float | None = None,
        gamma: float | str | None = None,
        per_pad: bool = PAPER_MODEL["per_pad"],
        pad_sizes: Sequence[int] | None = None,
        random_state=0,
        assignment: str = "hard",
        temperature: float = 1.0,
        level_features: bool = False,
        scale_features: bool = False,
        max_windows: int = 200000,
        fullscale: float = 4095.0,
    ):
        self.n_words = n_words
        self.window = window
        self.kernel = kernel
        self.C = C
        self.gamma = gamma
        self.per_pad = per_pad
        self.pad_sizes = pad_sizes
        self.random_state = random_state
        self.assignment = assignment
        self.temperature = temperature
        self.level_features = level_features
        self.scale_features = scale_features
        self.max_windows = max_windows
        self.fullscale = fullscale

    def fit(self, X, y):
        X, y, self.classes_ = check_training_data(self, X, y)
        self.bow_ = BagOfWords(
            n_words=self.n_words,
            window=self.window,
            per_pad=self.per_pad,
            pad_sizes=self.pad_sizes,
            random_state=self.random_state,
            assignment=self.assignment,
            temperature=self.temperature,
            level_features=self.level_features,
            max_windows=self.max_windows,
            fullscale=self.fullscale,
        ).fit(X)
        hist = self.bow_.transform(X)
        self.scaler_ = StandardScaler().fit(hist) if self.scale_features else None
        self._fit_svm(self.svm_input(hist), y)
        self.n_features_in_ = self.bow_.n_features_in_
        return self

    def svm_input(self, hist: np.ndarray) -> np.ndarray:
        """What the SVM sees: the BoW features, standardised when ``scale_features``."""
        scaler = getattr(self, "scaler_", None)
        return hist if scaler is None else scaler.transform(hist)

    def transform_histograms(self, X) -> np.ndarray:
        """The BoW features before any scaling (the graph's ``histogram``; t-SNE, diagnostics)."""
        check_is_fitted(self, "svm_")
        return self.bow_.transform(X)

