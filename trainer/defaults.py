"""The product's default classifier, defined once: what ``handover train`` exports without options.

The paper's hand-designed features plus per-pad level statistics (``hand``, ``stats``), standardised,
a quantity both families compute counted once (``feature_weighting = "distinct"``), linear SVM (C
searched); chosen by ``trainer.default_choice`` (results/compare.md, "Choosing the default"). The
paper's configuration stays reachable: ``handover train --no-per-pad --features bow``.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = [
    "BOW_ALONE_KERNEL", "DEFAULT_MODEL", "PAPER_MODEL", "default_candidate_name", "default_classifier",
    "describe_default", "paper_classifier"
]

DEFAULT_MODEL = {
    "families": ("hand", "stats"),
    "kernel": "linear",
    "feature_weighting": "distinct",
    "K": 10,
    "W": 7,
    "T": 15,
    "pads": "all",
    "per_pad": True,
}
"""Feature families, SVM kernel, weighting of the standardised features, BoW words/window, frames per case, pads. ``per_pad``: the BoW
family keeps one histogram per pad (the paper's single histogram is ``per_pad=False``)."""

def describe_default() -> str:
    """One phrase for results files, e.g. ``hand + stats features (distinct), linear SVM, T=15, all pads``."""
    m = DEFAULT_MODEL
    weighting = f" ({m['feature_weighting']})" if m["feature_weighting"] else ""
    return f"{' + '.join(m['families'])} features{weighting}, {m['kernel']} SVM, T={m['T']}, {m['pads']} pads"


def default_candidate_name() -> str:
    """The default as a candidate of ``handover train --select`` is named, e.g. ``hand+stats linear distinct``."""
    m = DEFAULT_MODEL
    return " ".join(x for x in ("+".join(m["families"]), m["kernel"], m["feature_weighting"]) if x)


BOW_ALONE_KERNEL = "linear"
"""Kernel of the BoW family alone (``handover train --features bow``): with per-pad histograms it
matches RBF's error on the simulated protocol and is faster (results/pareto.md)."""

PAPER_MODEL = {"families": ("bow",), "kernel": "rbf", "K": 10, "W": 7, "T": 15, "pads": "all", "per_pad": False}
"""Davari et al.'s configuration: one derivative-window histogram per case, RBF SVM (also
``BowSVC``'s own defaults)."""


def paper_classifier(pad_sizes: Sequence[int] | None = None, random_state: int = 0, **changes):
    """The unfitted BoW + SVM estimator (``BowSVC``): the paper's configuration (``PAPER_MODEL``)
    with ``changes`` (BowSVC settings that depart from it: per-pad histograms, level features,
    another K, W, kernel or C). Every BowSVC of the trainer is built here. ``pad_sizes`` (channels
    per pad, in channel order) is kept only where a setting uses it (per-pad histograms or level
    features), so the paper's estimator reads all channels as one series set."""
    from trainer.classifier import BowSVC

    model = BowSVC(random_state=random_state, **changes)
    if model.per_pad or model.level_features:
        model.set_params(pad_sizes=pad_sizes)
    return model


def default_classifier(pad_sizes: Sequence[int], pad_shapes: Sequence[tuple[int, int]] | None = None,
                       random_state: int = 0, fullscale: float = 4095.0):
    """The unfitted default estimator (scikit-learn API) for cases ``(n_cases, n_channels, n_timepoints)``
    whose channels are the pads ``pad_sizes`` in wire order (e.g. ``[78, 78, 78]``: the three distal
    pads), with the features and settings ``handover train`` exports. ``pad_shapes`` (rows, cols)
    default to SDH-2 pads, 6 taxels wide. Any ``n_timepoints`` of at least 2 fits (the product uses
    ``DEFAULT_MODEL["T"]``); once fitted, the model takes cases of that same length only."""
    from trainer.feature_svc import FeatureSVC

    return FeatureSVC(families=DEFAULT_MODEL["families"], pad_sizes=tuple(int(s) for s in pad_sizes),
                      pad_shapes=pad_shapes, kernel=DEFAULT_MODEL["kernel"], n_words=DEFAULT_MODEL["K"],
                      window=DEFAULT_MODEL["W"], random_state=random_state, fullscale=fullscale,
                      feature_weighting=DEFAULT_MODEL["feature_weighting"])
