"""Early heads and their report rule, fitted on training data only.

Why: a decision at T frames answers about half a second late, while many events are plain after a few
frames. For each point of ``EARLY_POINTS`` a head of the default kind is trained on the first ``p``
frames, and the report rule (``runtime.early``) is chosen by grouped cross-validation inside the
training data: out-of-fold answers, Platt scaling of each head's score margin, then the rule with the
fewest mean frames whose accuracy stays within ``target_loss`` of the full window's on *every* kind of
case (``case_kinds``: a wrong action and a false event on a dormant window fail differently, and a loss
allowed over all cases could fall on one kind). ``evaluate`` nests the whole choice inside
leave-one-group-out for an honest report; ``Fits`` fits each leave-groups-out model once.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
from scipy.special import expit

from runtime.decision import margin_of
from runtime.early import NEVER, EarlySpec
from trainer.dormant import DORMANT

__all__ = [
    "EARLY_POINTS",
    "TARGET_LOSS",
    "EarlyHeads",
    "Fits",
    "answers",
    "cascade",
    "choose_rule",
    "confidences",
    "earliness_score",
    "evaluate",
    "fit_early",
    "fit_stream_heads",
    "fold_heads",
    "head_factory",
    "part_problem",
    "platt",
    "rule_in_words"
]

EARLY_POINTS = (4, 6, 8, 11)
"""Frames after the window's start at which a head decides (the full model answers at T)."""
TARGET_LOSS = 0.02
"""The rule may lose at most this much accuracy against the full window (cross-validated), on every
kind of case (``case_kinds``)."""
THRESHOLDS = (0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.93, 0.95, 0.97, 0.98, 0.99, 0.995, 0.999)
"""The grid of calibrated-confidence thresholds the rule is chosen from (and ``NEVER``: all at T)."""

Factory = Callable[[int], object]
"""Unfitted estimator for windows of ``p`` frames (``p`` = T: the full model)."""


HEAD_C_GRID = (100.0, 10.0, 1.0, 0.1)
"""The C a head is chosen from: the default's grid reaches 1e6 (a hard margin where training cases
are separable); a few frames of five classes are not, and libsvm then takes minutes per large-C fit."""


def head_factory(pad_sizes: Sequence[int], pad_shapes=None, seed: int = 0, fullscale: float = 4095.0) -> Factory:
    """Heads of the default kind (the default's features and C search, over ``HEAD_C_GRID``)."""
    from trainer.defaults import default_classifier

    return lambda p: default_classifier(pad_sizes, pad_shapes, random_state=seed, fullscale=fullscale).set_params(
        c_grid=HEAD_C_GRID)


def answers(models: Sequence, points: Sequence[int], X: np.ndarray, classes: Sequence[str],
            features: Sequence[np.ndarray | None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Labels (indices into ``classes``) ``[n_points, n]`` and score margins ``[n_points, n]``;
    ``features``: per model, its features of ``X`` computed before (``FeatureSVC.case_features``) or None."""
    index = {c: i for i, c in enumerate(classes)}
    labels = np.zeros((len(points), len(X)), dtype=np.int64)
    margins = np.zeros((len(points), len(X)))
    for k, (model, p) in enumerate(zip(models, points, strict=True)):
        given = None if features is None else features[k]
        scores, predicted = (model.scores_and_labels(X[:, :, :p], given) if hasattr(model, "scores_and_labels")
                             else (model.decision_function(X[:, :, :p]), model.predict(X[:, :, :p])))
        scores = np.asarray(scores, dtype=np.float64)
        if scores.ndim == 1:  # two classes: one decision value; the graph's ovr-style pair (votes + confidence)
            c = np.abs(scores) / (3.0 * (np.abs(scores) + 1.0))
            scores = np.stack([(scores <= 0) + np.where(scores <= 0, c, -c), (scores > 0) + np.where(scores > 0, c, -c)],
                              axis=1)
        pred = [index[str(c)] for c in predicted]
        own = [list(model.classes_).index(classes[i]) for i in pred]
        labels[k] = pred
        margins[k] = [margin_of(scores[j], own[j]) for j in range(len(X))]
    return labels, margins


class Fits:
    """Heads (and the full model, last) trained without some groups, each fitted once and kept: the
    nested evaluation and the final rule need the same leave-groups-out models many times."""

    def __init__(self, X: np.ndarray, y: np.ndarray, groups: np.ndarray, points: Sequence[int], make: Factory,
                 make_full: Factory) -> None:
        self.X, self.y, self.groups = X, np.asarray(y), np.asarray(groups).astype(str)
        self.T = X.shape[2]
        self.points = tuple(int(p) for p in points)
        self.all_points = (*self.points, self.T)
        self.make, self.make_full = make, make_full
        self.classes = sorted({str(c) for c in self.y})
        self.truth = np.asarray([self.classes.index(str(c)) for c in self.y])
        self.dormant = self.classes.index(DORMANT) if DORMANT in self.classes else -1
        """The dormant class's index (-1: none): never reported early (``choose_rule``)."""
        self._models: dict[frozenset, list] = {}
        self.per_class = False
        """Whether the rule also chooses which actions may come early (``choose_rule``'s ``classes``)."""
        self.searched_once = False
        """Whether models trained without some groups take the C (and gamma) the model on every group chose
        instead of searching again: for a rule fitted once (``fit_early``), not for ``evaluate``'s nested
        report (the held-out group would then have helped choose them)."""
        self._features: dict[int, np.ndarray | None] = {}
        """Per point, every case's features where the model's depend on the case alone (``case_features``):
        computed once, not in each of the many fits and answers on subsets of these cases."""

    def _case_features(self, k: int, model) -> np.ndarray | None:
        if k not in self._features:
            compute = getattr(model, "case_features", None)  # None: e.g. a head trained with the prior
            self._features[k] = None if compute is None else compute(self.X[:, :, :self.all_points[k]])
        return self._features[k]

    def features_of(self, rows) -> list[np.ndarray | None]:
        """Per point (of models fitted before), the features of the cases ``rows`` (or None): ``answers``."""
        return [None if (f := self._features.get(k)) is None else f[rows] for k in range(len(self.all_points))]

    def models(self, excluded: frozenset, full: bool = True) -> list:
        """The heads (and with ``full`` the full model) trained on every group but ``excluded``."""
        kept = ~np.isin(self.groups, list(excluded))
        have = self._models.setdefault(excluded, [])
        want = len(self.all_points) if full else len(self.points)
        for k in range(len(have), want):
            p = self.all_points[k]
            model = (self.make if p < self.T else self.make_full)(p)
            if self.searched_once and excluded:
                model.set_params(**self.models(frozenset(), full=k == len(self.points))[k].best_params_)
            features = self._case_features(k, model)
            given = {} if features is None else {"features": features[kept]}
            have.append(model.fit(self.X[kept, :, :p], self.y[kept], **given))
        return have[:want]

    def out_of_fold(self, excluded: frozenset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Labels and margins ``[n_points + 1, n]`` of the cases outside ``excluded``, each group's cases
        answered by the models trained without it (and without ``excluded``), and their index."""
        index = np.flatnonzero(~np.isin(self.groups, list(excluded)))
        labels = np.zeros((len(self.all_points), len(index)), dtype=np.int64)
        margins = np.zeros((len(self.all_points), len(index)))
        names = sorted(set(self.groups[index].tolist()))
        if len(names) < 2:
            raise ValueError("out-of-fold answers need at least two groups")
        for g in names:
            at = self.groups[index] == g
            models = self.models(excluded | {g})
            labels[:, at], margins[:, at] = answers(models, self.all_points, self.X[index[at]], self.classes,
                                                    self.features_of(index[at]))
        return labels, margins, index


def platt(margins: np.ndarray, correct: np.ndarray, iterations: int = 50) -> tuple[float, float]:
    """``(a, b)`` with P(correct | m) = sigmoid(a m + b), fitted by Newton's method on Platt's smoothed
    targets (so a head that was never wrong still gets a finite, cautious calibration)."""
    m = np.asarray(margins, dtype=np.float64)
    c = np.asarray(correct, dtype=bool)
    n_pos, n_neg = int(c.sum()), int((~c).sum())
    t = np.where(c, (n_pos + 1.0) / (n_pos + 2.0), 1.0 / (n_neg + 2.0))
    a, b = 0.0, float(np.log((n_pos + 1.0) / (n_neg + 1.0)))
    for _ in range(iterations):
        p = expit(a * m + b)
        w = p * (1.0 - p) + 1e-12
        g = np.array([np.sum((p - t) * m), np.sum(p - t)])
        h = np.array([[np.sum(w * m * m), np.sum(w * m)], [np.sum(w * m), np.sum(w)]]) + 1e-9 * np.eye(2)
        step = np.linalg.solve(h, g)
        a, b = a - step[0], b - step[1]
        if np.abs(step).max() < 1e-10:
            break
    return float(a), float(b)


def confidences(margins: np.ndarray, calibration: Sequence[tuple[float, float]]) -> np.ndarray:
    ab = np.asarray(calibration, dtype=np.float64)
    return expit(ab[:, :1] * margins + ab[:, 1:])  # no overflow warning for a large margin


def cascade(labels: np.ndarray, conf: np.ndarray, full: np.ndarray, needs: np.ndarray, agree: bool
            ) -> tuple[np.ndarray, np.ndarray]:
    """Where the rule reports each case (index of the point, ``len(points)`` = T) and what it says.

    ``labels``/``conf``: ``[n_points, n]`` of the early heads; ``full``: the full model's labels;
    ``needs``: per class index, the confidence it needs to be reported early (``EarlySpec.needs``;
    ``NEVER``: the class waits for T)."""
    n_points, n = labels.shape
    needs = np.asarray(needs, dtype=np.float64)
    where = np.full(n, n_points, dtype=np.int64)
    said = full.copy()
    open_ = np.ones(n, dtype=bool)
    for k in range(n_points):
        ok = open_ & (conf[k] >= needs[labels[k]])
        if agree:
            ok &= labels[k] == labels[k - 1] if k > 0 else False
        where[ok], said[ok] = k, labels[k][ok]
        open_ &= ~ok
    return where, said


@dataclass
class RuleChoice:
    spec: EarlySpec
    accuracy: float
    full_accuracy: float
    mean_frames: float
    grid: list[dict]


def case_kinds(truth: np.ndarray, dormant: int = -1) -> dict[str, np.ndarray]:
    """The kinds of case whose accuracy the rule keeps one by one (bool masks over ``truth``): the
    action cases, and the dormant cases where ``dormant`` (a class index, -1: none) has any."""
    actions = truth != dormant
    kinds = {"actions": actions}
    if dormant >= 0 and (~actions).any():
        kinds["dormant"] = ~actions
    return kinds


def rule_in_words(target_loss: float = TARGET_LOSS) -> str:
    """The rule in words, for the reports that state it (trainer.early_report, the streams_own bench)."""
    return ("the early report rule (threshold on the calibrated confidence, agree or not) with the fewest mean "
            f"frames whose leave-one-subject-out accuracy inside the training data stays within {target_loss:.0%} "
            "of the full window's on the action cases and, with a dormant class, on the dormant cases (a dormant "
            "window answered with an action is a false event)")


def early_class_sets(n_classes: int, dormant: int, per_class: bool) -> list[tuple[int, ...] | None]:
    """The sets of classes the rule may let come early: all reported classes (None), and with ``per_class``
    every non-empty subset of the actions (a class whose early answers cost false events can wait for T)."""
    actions = [c for c in range(n_classes) if c != dormant]
    subsets = [s for n in range(len(actions) - 1, 0, -1) for s in combinations(actions, n)] if per_class else []
    return [None, *subsets]


def choose_rule(labels: np.ndarray, margins: np.ndarray, full: np.ndarray, truth: np.ndarray,
                points: Sequence[int], T: int, target_loss: float = TARGET_LOSS, dormant: int = -1,
                classes: Sequence[str] | None = None) -> RuleChoice:
    """The calibration and the rule (see the module docstring) from out-of-fold answers.

    ``dormant``: index of the dormant class (-1: none). A dormant answer is never reported early (the
    window waits for a later head or T, as the daemon does); the accuracy on the dormant cases is the
    false-event side of the rule, kept like the actions' (``case_kinds``). ``classes`` (the class names,
    by index): also choose which actions may come early (``early_class_sets``; ties: the most classes)."""
    calibration = [platt(margins[k], labels[k] == truth) for k in range(len(points))]
    conf = confidences(margins, calibration)
    frames = np.asarray([*points, T], dtype=np.float64)
    n = max(int(labels.max(initial=0)), int(truth.max()), dormant, len(classes or ()) - 1) + 1
    kinds = {k: m for k, m in case_kinds(truth, dormant).items() if m.any()}
    full_acc = float(np.mean(full == truth))
    full_kinds = {k: float(np.mean(full[m] == truth[m])) for k, m in kinds.items()}
    grid = []
    for subset in early_class_sets(n, dormant, classes is not None):
        allowed = (np.arange(n) != dormant) if subset is None else np.isin(np.arange(n), subset)
        for agree in (False, True):
            for threshold in (*THRESHOLDS, NEVER):
                where, said = cascade(labels, conf, full, np.where(allowed, threshold, NEVER), agree)
                grid.append({"threshold": threshold, "agree": agree, "accuracy": float(np.mean(said == truth)),
                             **{f"{k}_accuracy": float(np.mean(said[m] == truth[m])) for k, m in kinds.items()},
                             "mean_frames": float(frames[where].mean()),
                             "classes": None if subset is None else [classes[c] for c in subset]})
    feasible = [r for r in grid if r["accuracy"] >= full_acc - target_loss - 1e-12
                and all(r[f"{k}_accuracy"] >= full_kinds[k] - target_loss - 1e-12 for k in kinds)]
    best = min(feasible, key=lambda r: (round(r["mean_frames"], 9), -r["accuracy"], -r["threshold"], -r["agree"],
                                        -len(r["classes"] if r["classes"] is not None else range(n))), default=None)
    assert best is not None  # NEVER reproduces the full window's accuracy
    spec = EarlySpec(tuple(int(p) for p in points), tuple(calibration), float(best["threshold"]), bool(best["agree"]),
                     None if best["classes"] is None else tuple(best["classes"]))
    return RuleChoice(spec, best["accuracy"], full_acc, best["mean_frames"], grid)


def part_problem(groups: np.ndarray, y: np.ndarray) -> str | None:
    """Why the nested evaluation cannot fit every head: a training part (all groups but two) holding fewer
    than two classes, e.g. a subject of one trial (a trial names its own subject), named with its cases;
    None when every part can be fitted."""
    groups, y = np.asarray(groups).astype(str), np.asarray(y)
    for pair in combinations(sorted(set(groups.tolist())), 2):
        rest = ~np.isin(groups, pair)
        if len(have := sorted(set(y[rest].tolist()))) < 2:
            who, n = ", ".join(sorted(set(groups[rest].tolist()))), int(rest.sum())
            return (f"leaving out {pair[0]} and {pair[1]} would train on {who} alone ({n} case{'s' * (n != 1)}, all "
                    f"{have[0] if have else 'none'}); record every class for each subject (or check the trials' "
                    "subject ids)")
    return None


def fit_rule(fits: Fits, excluded: frozenset = frozenset(), target_loss: float = TARGET_LOSS) -> RuleChoice:
    """The rule chosen by leave-one-group-out among the groups outside ``excluded`` (the training data)."""
    labels, margins, index = fits.out_of_fold(excluded)
    return choose_rule(labels[:-1], margins[:-1], labels[-1], fits.truth[index], fits.points, fits.T, target_loss,
                       fits.dormant, fits.classes if fits.per_class else None)


def evaluate(fits: Fits, target_loss: float = TARGET_LOSS, say: Callable[[str], None] | None = None) -> dict:
    """Nested leave-one-group-out: the accuracy-against-frames curve (overall and per class) of the
    heads, and the operating point of the rule chosen inside each outer training part."""
    classes, truth, all_points = fits.classes, fits.truth, fits.all_points
    n = len(truth)
    labels = np.zeros((len(all_points), n), dtype=np.int64)
    where = np.zeros(n, dtype=np.int64)
    said = np.zeros(n, dtype=np.int64)
    rules = []
    names = sorted(set(fits.groups.tolist()))
    for i, g in enumerate(names):
        if say:
            say(f"early decisions: outer fold {i + 1}/{len(names)} (held out {g}) ...")
        test = fits.groups == g
        choice = fit_rule(fits, frozenset({g}), target_loss)
        lab, mar = answers(fits.models(frozenset({g})), all_points, fits.X[test], classes, fits.features_of(test))
        labels[:, test] = lab
        conf = confidences(mar[:-1], choice.spec.calibration)
        w, s = cascade(lab[:-1], conf, lab[-1], choice.spec.needs(classes, DORMANT), choice.spec.agree)
        where[test], said[test] = w, s
        rules.append({"held_out": str(g), **choice.spec.to_meta(), "inner_accuracy": choice.accuracy,
                      "inner_full_accuracy": choice.full_accuracy, "inner_mean_frames": choice.mean_frames})
    frames = np.asarray(all_points)
    curve = {str(p): float(np.mean(labels[k] == truth)) for k, p in enumerate(all_points)}
    per_class = {c: {str(p): float(np.mean(labels[k][truth == i] == i)) for k, p in enumerate(all_points)}
                 for i, c in enumerate(classes)}
    op_class = {c: {"accuracy": float(np.mean(said[truth == i] == i)),
                    "mean_frames": float(frames[where[truth == i]].mean())} for i, c in enumerate(classes)}
    return {"points": list(all_points), "classes": classes, "curve": curve, "curve_per_class": per_class,
            "operating_point": {"accuracy": float(np.mean(said == truth)), "mean_frames": float(frames[where].mean()),
                                "median_frames": float(np.median(frames[where])), "per_class": op_class,
                                "reported_at": {str(p): int(np.sum(where == k)) for k, p in enumerate(all_points)}},
            "full_accuracy": curve[str(fits.T)], "target_loss": target_loss, "rules": rules, "n_cases": n}


def earliness_score(accuracy: float, mean_frames: float, T: int) -> dict:
    """Earliness (fraction of the window used, lower is earlier) and the harmonic mean of accuracy and
    1 - earliness, the usual score of early classification."""
    earliness = mean_frames / T
    hm = 0.0 if accuracy <= 0 or earliness >= 1 else 2 * accuracy * (1 - earliness) / (accuracy + 1 - earliness)
    return {"accuracy": accuracy, "earliness": earliness, "harmonic_mean": hm}


@dataclass
class EarlyHeads:
    """Fitted heads (one per point of ``spec.points``) and the rule: what the exporter puts in the file."""

    models: list
    spec: EarlySpec
    choice: RuleChoice | None = None
    folds: dict[str, EarlyHeads] = field(default_factory=dict)
    """Per held-out group, the heads and rule chosen without it (``fold_heads``): the held-out replay's."""


def fold_heads(fits: Fits, rules: Sequence[dict]) -> dict[str, EarlyHeads]:
    """The nested evaluation's heads and rule for each held-out group (``evaluate``'s ``rules``): fitted
    already, so the held-out replay scores early reports without new fits."""
    keys = ("points", "calibration", "threshold", "agree", "classes")
    return {r["held_out"]: EarlyHeads(fits.models(frozenset({r["held_out"]}), full=False),
                                      EarlySpec.from_meta({k: r[k] for k in keys if k in r}, fits.T)) for r in rules}


def fit_early(X: np.ndarray, y: np.ndarray, groups: np.ndarray, make: Factory, make_full: Factory,
              points: Sequence[int] = EARLY_POINTS, target_loss: float = TARGET_LOSS, fits: Fits | None = None
              ) -> EarlyHeads:
    """Heads on all of ``X`` and the rule chosen by leave-one-group-out inside it (``fits``: models
    already fitted for these data, e.g. by ``evaluate``)."""
    if fits is None:
        fits = Fits(X, y, groups, tuple(p for p in points if p < X.shape[2]), make, make_full)
    choice = fit_rule(fits, frozenset(), target_loss)
    return EarlyHeads(fits.models(frozenset(), full=False), choice.spec, choice)


def fold_groups(groups: np.ndarray) -> np.ndarray:
    """Subjects as folds, each idle-stream fifth (``idle<i>``) joined to the i-th subject's fold (as
    ``trainer.dormant.leave_one_subject_out`` holds them out)."""
    groups = np.asarray(groups).astype(str)
    subjects = sorted({g for g in groups.tolist() if not g.startswith("idle")})
    idle = sorted({g for g in groups.tolist() if g.startswith("idle")})
    if not subjects:
        return groups
    join = {g: subjects[i % len(subjects)] for i, g in enumerate(idle)}
    return np.asarray([join.get(g, g) for g in groups.tolist()])


def stream_cases(protocol, dds, pads) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Training windows of the stream model's heads: the actions cut where the daemon's onset trigger
    starts a window (trainer.dataset) and the dormant windows of the stream model's data set."""
    from trainer.dataset import build_dataset

    ds = build_dataset(protocol, T=dds.T, pads=pads)
    dormant = dds.y == DORMANT
    X = np.concatenate([ds.X, dds.X[dormant]]).astype(np.float32)
    y = np.concatenate([ds.y.astype(str), dds.y[dormant]])
    return X, y, fold_groups(np.concatenate([ds.groups.astype(str), dds.groups[dormant]]))


def fit_stream_heads(protocol, dds, pads, seed: int, points: Sequence[int] = EARLY_POINTS,
                     target_loss: float = TARGET_LOSS, log: Callable[[str], None] | None = None) -> EarlyHeads:
    """Early heads of the 5-class stream model (``trainer.dormant.fit_stream_model``). The full window's
    answers in the rule's cross-validation come from a head of the same kind at T: the stream model's
    own estimator (RBF, C and gamma searched) refitted per fold would multiply the demo's training time."""
    X, y, groups = stream_cases(protocol, dds, pads)
    if log:
        log(f"early heads at {', '.join(map(str, points))} frames on {len(y)} windows, rule by leave-one-subject-out ...")
    make = head_factory(dds.pad_sizes, seed=seed, fullscale=dds.fullscale)
    fits = Fits(X, y, groups, tuple(p for p in points if p < X.shape[2]), make, make)
    fits.searched_once = True  # a fold's C search repeated per held-out fold was most of the demo's training
    heads = fit_early(X, y, groups, make, make, points, target_loss, fits)
    if log and heads.choice is not None:
        c = heads.choice
        log(f"early rule: threshold {heads.spec.threshold:g}, agree {heads.spec.agree}: cross-validated accuracy "
            f"{c.accuracy:.1%} (full window {c.full_accuracy:.1%}) at {c.mean_frames:.1f} frames on average")
    return heads
