"""The float64 reference of the exported graph and the float32 error bounds that define a near tie.

Why bounds: the ONNX graph computes in float32 and the reference in float64, so a decision may
legitimately differ where two alternatives are closer than float32 can tell apart. A difference
is accepted only when it is such a *near tie*, defined here with standard rounding-error
analysis (Higham, *Accuracy and Stability of Numerical Algorithms*, ch. 3): with unit roundoff
``u = 2**-24`` and ``gamma(n) = n u / (1 - n u)``, a float32 sum of n products whose inputs are
themselves rounded once is within ``gamma(n + 3) * sum |terms|`` of the exact value, in any
summation order (FMA or not).

**Codeword near tie.** The graph picks ``argmin_k f_k`` with ``f_k = ||c_k||^2 - 2 w.c_k``,
w the float32 derivative window (exact for integer inputs). Its float32 error is at most
``E_k = gamma(W + 3) * B_k`` with ``B_k = ||c_k||^2 + 2 sum_j |w_j| |c_kj|`` (raw values
``x`` and the folded kernel instead of ``w`` and ``c`` when the derivative is folded). The
float64 squared distances satisfy ``d_k - d_best = f_k - f_best`` exactly, so the graph can
prefer ``k`` over the reference's ``best`` only if ``d_k - d_best <= E_k + E_best``. A window is
a near tie when some k has ``d_k - d_best <= SAFETY * (E_k + E_best)``; its *relative margin* is
``min_k (d_k - d_best) / (E_k + E_best)`` (in units of the bound, near tie below SAFETY).

**Soft assignment** has no near tie: the float32 weights differ from the float64 ones by a
bounded amount. With ``z_k = -(d_k - d_min) / tau`` the graph's exponent is off by at most
``dz_k = (E_k + E_min) / tau + 4 u (|z_k| + 1)``, and a softmax moves by
``|dp_k| <= p_k * expm1(dz_k + sum_j p_j dz_j)`` (plus ``gamma(K + 4) p_k`` for its own
rounding); summed over windows this bounds every histogram entry (``histogram_error_bounds``).
**Level features** are sums of float32 values: ``gamma(T + C + 4)`` times the sum of |terms|.
These entry bounds are carried into the SVM bound (``svm_decision_bounds(..., input_error)``),
through the StandardScaler when there is one (folded into the RBF kernel: ``trainer.svm_head``).

**SVM near tie.** A one-vs-one decision ``dec_p = sum_m a_mp K_m + b_p`` computed in float32 is
within ``E_p`` of the float64 value (bound from ``svm_decision_bounds``); its vote can flip only
when ``|dec_p| <= E_p``, a near tie with ``SAFETY``. ``SAFETY = 2`` absorbs second-order terms.
"""

from __future__ import annotations

import copy

import numpy as np

from trainer.onnx_export import folded_codebook, svm_pair_coefficients, vote_matrices

__all__ = [
    "SAFETY", "U32", "codeword_margins", "gamma", "rbf_decision_bounds", "reference", "svm_decision_bounds",
    "window_codewords"
]

U32 = 2.0**-24
SAFETY = 2.0


def gamma(n: int) -> float:
    return n * U32 / (1.0 - n * U32)


# -- codewords --------------------------------------------------------------------------------
def codeword_margins(X: np.ndarray, codebook: np.ndarray, fold_derivative: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Relative margin of every window, float64 ``(n, c, S)``: the smallest gap to another codeword
    in units of its float32 error bound (< SAFETY: near tie; inf with a single codeword), and the
    absolute gap between the two smallest squared distances.

    ``X`` is ``(n, c, T)`` of the float32 values the graph sees (cast to float64). An all-zero
    series (most taxels of a window) has the margins of the zero series: computed once and copied,
    which keeps ``handover verify`` fast and its memory small.
    """
    X = np.asarray(X, dtype=np.float64)
    active = np.any(X != 0, axis=2)
    if active.all():
        return _codeword_margins(X, codebook, fold_derivative)
    zero_rel, zero_gap = _codeword_margins(np.zeros((1, 1, X.shape[2])), codebook, fold_derivative)
    rel = np.broadcast_to(zero_rel, (*X.shape[:2], zero_rel.shape[2])).copy()
    gap = np.broadcast_to(zero_gap, rel.shape).copy()
    if active.any():
        r, g = _codeword_margins(X[active][None], codebook, fold_derivative)
        rel[active], gap[active] = r[0], g[0]
    return rel, gap


def squared_distances(X: np.ndarray, codebook: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The derivative windows ``(n, c, S, W)`` of float64 ``X`` ``(n, c, T)`` and their float64 squared
    distances to every codeword ``(n, c, S, K)`` (expanded form, not clipped at 0: what every
    reference here starts from)."""
    deriv = X[:, :, 1:] - X[:, :, :-1]
    win = np.lib.stride_tricks.sliding_window_view(deriv, codebook.shape[1], axis=2)  # (n, c, S, W)
    # expanded form is fine in float64: its rounding (~1e-16 * scale) is far below the float32 bound
    return win, (win**2).sum(axis=-1)[..., None] - 2.0 * win @ codebook.T + (codebook**2).sum(axis=1)


def distance_error_bounds(X: np.ndarray, win: np.ndarray, codebook: np.ndarray, fold_derivative: bool) -> np.ndarray:
    """``E_k``, the float32 error bound of the graph's ``f_k`` for every window and codeword ``(n, c, S, K)``
    (raw values and the folded kernel when the graph folds the derivative)."""
    window = codebook.shape[1]
    sqnorm = (codebook**2).sum(axis=1)
    if fold_derivative:
        kernel = np.abs(folded_codebook(codebook))  # (K, W+1)
        raw = np.lib.stride_tricks.sliding_window_view(X, window + 1, axis=2)
        return gamma(window + 3) * (sqnorm + 2.0 * np.abs(raw) @ kernel.T)
    return gamma(window + 3) * (sqnorm + 2.0 * np.abs(win) @ np.abs(codebook).T)


def _codeword_margins(X: np.ndarray, codebook: np.ndarray, fold_derivative: bool) -> tuple[np.ndarray, np.ndarray]:
    codebook = np.asarray(codebook, dtype=np.float64)
    n_words = codebook.shape[0]
    win, dist = squared_distances(X, codebook)
    dist = np.maximum(dist, 0.0)  # (n, c, S, K)
    err = distance_error_bounds(X, win, codebook, fold_derivative)
    best = np.argmin(dist, axis=-1)[..., None]
    d_best = np.take_along_axis(dist, best, axis=-1)
    e_best = np.take_along_axis(err, best, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = (dist - d_best) / (err + e_best)
    others = np.arange(n_words) == best
    rel = np.where(others, np.inf, rel).min(axis=-1)
    gap = np.where(others, np.inf, dist - d_best).min(axis=-1)
    return rel, gap


def window_codewords(X: np.ndarray, codebook: np.ndarray, fold_derivative: bool = False
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Float64 nearest codeword of every window ``(n, c, S)`` (ties -> lowest k) and its relative
    margin (as ``codeword_margins``): what the graph's ArgMin must reproduce window by window."""
    X64 = np.asarray(X, dtype=np.float64)
    codebook = np.asarray(codebook, dtype=np.float64)
    _, dist = squared_distances(X64, codebook)
    rel, _ = codeword_margins(X64, codebook, fold_derivative)
    return np.argmin(dist, axis=-1), rel


def case_codeword_margins(X: np.ndarray, codebook: np.ndarray, fold_derivative: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per case, the smallest relative codeword margin and absolute gap over its active windows."""
    rel, gap = codeword_margins(X, codebook, fold_derivative)
    active = np.any(np.asarray(X) != 0, axis=2)[:, :, None]
    rel = np.where(active, rel, np.inf).reshape(len(rel), -1).min(axis=1)
    gap = np.where(active, gap, np.inf).reshape(len(gap), -1).min(axis=1)
    return rel, gap


# -- SVM ----------------------------------------------------------------------------------------
def svm_pair_decisions(svm, hist: np.ndarray) -> np.ndarray:
    """Float64 one-vs-one decisions ``(n, P)`` with libsvm's sign (> 0 votes for the first class),
    from scikit-learn itself."""
    if len(svm.classes_) == 2:
        return -np.asarray(svm.decision_function(hist), dtype=np.float64)[:, None]
    ovo = copy.copy(svm)
    ovo.decision_function_shape = "ovo"
    return np.asarray(ovo.decision_function(hist), dtype=np.float64)


def svm_decision_bounds(svm, hist: np.ndarray, input_error: np.ndarray | None = None, scaler=None) -> np.ndarray:
    """Float32 error bound ``E_p`` of each one-vs-one decision of the graph, ``(n, P)``.

    ``hist``: the SVM's features before ``scaler`` (None: no scaler); ``input_error`` ``(n, F)``: a
    bound on how far the graph's features may be from ``hist`` (soft histograms, families); zero
    when None. The arithmetic bounded is ``trainer.svm_head``'s.
    """
    hist = np.asarray(hist, dtype=np.float64)
    delta = np.zeros_like(hist) if input_error is None else np.asarray(input_error, dtype=np.float64)
    coef, intercept, _ = svm_pair_coefficients(svm)
    if svm.kernel == "rbf":
        return rbf_decision_bounds(svm, scaler, hist, delta, coef, intercept)
    from trainer.svm_head import linear_constants

    # one Gemm on the raw features with the scaler folded in: F products, the intercept, stored constants
    weights, bias = (np.abs(v[..., : coef.shape[1]]) for v in linear_constants(svm, scaler))
    return gamma(hist.shape[1] + 4) * (np.abs(hist) @ weights + bias) + delta @ weights


def rbf_decision_bounds(svm, scaler, x: np.ndarray, delta: np.ndarray, coef: np.ndarray, intercept: np.ndarray
                        ) -> np.ndarray:
    """``E_p`` of the expanded RBF head (``trainer.svm_head``): ``u = (x - mean) * unit`` (three
    roundings, plus the features' own error ``delta``), ``||u||^2`` and the exponent's Gemm
    ``e = u . support - ||u||^2`` (sums of F terms: ``gamma(F + 3)`` times the sum of |terms|, no
    cancellation assumed away), then ``exp(e)`` times the coefficients (folded ``exp(offset)``:
    a few more roundings), summed over the M support vectors."""
    from trainer.svm_head import RbfConstants

    rbf = RbfConstants.of(svm, scaler)
    n_features = x.shape[1]
    mean = np.zeros(n_features) if rbf.mean is None else rbf.mean
    u = (x - mean) * rbf.unit
    du = gamma(3) * np.abs(u) + (1.0 + gamma(3)) * (delta + U32 * np.abs(mean)) * rbf.unit
    uu = np.abs(u) + du
    norm_err = (2.0 * np.abs(u) * du + du**2).sum(axis=1) + gamma(n_features + 1) * (uu**2).sum(axis=1)
    exponent = u @ rbf.support.T - (u**2).sum(axis=1)[:, None]  # float64: gamma (||sv||^2 - d)
    support = np.abs(rbf.support).T
    e_err = (gamma(n_features + 3) * (uu @ support + (uu**2).sum(axis=1)[:, None] + np.abs(exponent))
             + du @ support + norm_err[:, None])
    if not rbf.folded:
        e_err = e_err + U32 * np.abs(exponent + rbf.offset)
    log_kern = exponent + rbf.offset  # -gamma d: the float64 kernel's logarithm
    kern = np.exp(log_kern)
    growth = e_err + 8.0 * U32  # exp, the folded coefficient and the product
    # kern * expm1(growth), in log space where the factor would overflow (far-away stress cases:
    # kern underflows to 0 while expm1 is inf); capped below float64's largest, so a bound can be
    # huge but is never NaN.
    small = growth < 20.0
    k_err = np.where(small, kern * np.expm1(np.where(small, growth, 0.0)), np.exp(np.minimum(growth + log_kern, 709.0)))
    n_sv = kern.shape[1]
    with np.errstate(over="ignore"):  # a sum past float64's range is an infinite (always safe) bound
        return np.abs(kern) @ np.abs(coef) * gamma(n_sv + 3) + k_err @ np.abs(coef) + gamma(n_sv + 3) * np.abs(intercept)


def ovr_scores(dec: np.ndarray, n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """Votes (libsvm: ``dec > 0`` votes for the first class) and scikit-learn's ovr scores."""
    pairs = [(i, j) for i in range(n_classes) for j in range(i + 1, n_classes)]
    vote_diff, vote_base, conf_sign = vote_matrices(pairs, n_classes)
    votes = (dec > 0).astype(np.float64) @ vote_diff + vote_base
    conf = dec @ conf_sign
    return votes, votes + conf / (3.0 * (np.abs(conf) + 1.0))


# -- soft assignment and level features ---------------------------------------------------------
def soft_histogram_bounds(X: np.ndarray, codebook: np.ndarray, tau: float, pad_sizes, fold_derivative: bool = False
                          ) -> np.ndarray:
    """Bound on |graph - reference| of every soft-histogram entry of one scale, ``(n, G * K)``."""
    from trainer.bow import channel_groups

    X = np.asarray(X, dtype=np.float64)
    codebook = np.asarray(codebook, dtype=np.float64)
    n_words = codebook.shape[0]
    win, dist = squared_distances(X, codebook)
    dist = np.maximum(dist, 0.0)
    err = distance_error_bounds(X, win, codebook, fold_derivative)
    best = np.argmin(dist, axis=-1)[..., None]
    e_best = np.take_along_axis(err, best, axis=-1)
    z = -(dist - np.take_along_axis(dist, best, axis=-1)) / tau
    p = np.exp(z)
    p /= p.sum(axis=-1, keepdims=True)
    dz = (err + e_best) / tau + 4.0 * U32 * (np.abs(z) + 1.0)
    spread = (p * dz).sum(axis=-1, keepdims=True)
    dp = p * (np.expm1(np.minimum(dz + spread, 700.0)) + gamma(n_words + 4))  # (n, c, S, K)
    n_windows = win.shape[2]
    groups = channel_groups(pad_sizes)
    indicator = (groups[None, :] == np.arange(len(pad_sizes))[:, None]).astype(np.float64)
    active = np.any(X != 0, axis=2).astype(np.float64)
    summed = np.einsum("gc,nck->ngk", indicator, dp.sum(axis=2) * active[:, :, None])
    totals = (active @ indicator.T) * n_windows
    bound = np.where(totals[:, :, None] > 0, summed / np.maximum(totals, 1)[:, :, None], 0.0)
    bound = bound + gamma(int(n_windows * max(pad_sizes)) + 4)  # float32 sums of at most 1 and the division
    return bound.reshape(len(X), -1)


def level_feature_bounds(X: np.ndarray, level_groups, fullscale: float) -> np.ndarray:
    """Bound on |graph - reference| of the level features, ``(n, 2G)``."""
    from trainer.bow import level_features

    X = np.asarray(X, dtype=np.float64)
    n_t, n_c = X.shape[2], X.shape[1]
    mags = level_features(np.abs(X), level_groups, fullscale)
    groups = len(level_groups)
    level_err = gamma(n_t + n_c + 4) * mags[:, :groups]
    ends = np.abs(X[:, :, [0]]) + np.abs(X[:, :, [-1]])
    slope_mag = level_features(np.concatenate([np.zeros_like(ends), ends], axis=2), level_groups, fullscale)[:, groups:]
    return np.concatenate([level_err, gamma(n_c + 4) * slope_mag * (n_t - 1)], axis=1)


def histogram_error_bounds(model, X: np.ndarray, hist: np.ndarray, fold_derivative: bool = False) -> np.ndarray:
    """Bound ``(n, F)`` on how far the graph's ``histogram`` may be from the float64 one.

    Hard words are exact counts away from a codeword near tie (those are judged by the codeword
    margin), so only the final division's rounding counts there.
    """
    if hasattr(model, "feature_error_bounds"):  # FeatureSVC: each family bounds its own error
        return model.feature_error_bounds(X) + 2.0 * U32 * np.abs(hist)
    bow = getattr(model, "bow_", None)
    if bow is None:
        return np.zeros_like(hist)  # flattened series: float32 input values, exact in float64
    parts = []
    for _, codebook, tau in bow.scales():
        if getattr(bow, "assignment", "hard") == "soft":
            parts.append(soft_histogram_bounds(X, codebook, tau, bow.pad_sizes_, fold_derivative))
        else:
            parts.append(np.full((len(X), len(bow.pad_sizes_) * len(codebook)), 0.0))
    if getattr(bow, "level_features", False):
        parts.append(level_feature_bounds(X, bow.level_groups_, float(bow.fullscale)))
    out = np.concatenate(parts, axis=1)
    return out + 2.0 * U32 * np.abs(hist)


# -- the whole reference -------------------------------------------------------------------------
def reference(model, frames: np.ndarray, fold_derivative: bool = False) -> dict:
    """Float64 reference of the graph on float32 ``frames`` ``[N, T, C]``: histogram (and the bound
    on its float32 error), pair decisions, their bounds, labels (``svm_.predict``), ovr scores and
    codeword margins (inf where there is no hard codeword choice)."""
    X = np.asarray(frames, dtype=np.float32).astype(np.float64).transpose(0, 2, 1)
    hist = model.transform_histograms(X)
    hist_err = histogram_error_bounds(model, X, hist, fold_derivative)
    scaler = getattr(model, "scaler_", None)
    feats = hist if scaler is None else scaler.transform(hist)
    dec = svm_pair_decisions(model.svm_, feats)
    n_classes = len(model.classes_)
    _, scores = ovr_scores(dec, n_classes)
    labels = np.searchsorted(model.classes_, model.svm_.predict(feats))
    cw_margin = np.full(len(X), np.inf)
    cw_gap = np.full(len(X), np.inf)
    bow = getattr(model, "bow_", None)
    if bow is not None and getattr(bow, "assignment", "hard") == "hard":
        for _, codebook, _ in bow.scales():
            m, gp = case_codeword_margins(X, codebook, fold_derivative)
            cw_margin, cw_gap = np.minimum(cw_margin, m), np.minimum(cw_gap, gp)
    return {
        "hist": hist,
        "hist_error": hist_err,
        "decisions": dec,
        "decision_bounds": svm_decision_bounds(model.svm_, hist, hist_err, scaler),
        "labels": labels.astype(np.int64),
        "scores": scores,
        "codeword_margin": cw_margin,
        "codeword_gap": cw_gap,
    }
