"""The product's prior in a lab's training: what the simulator teaches, added to the lab's own cases.

Why: a lab records a few subjects (108 trials from 3 subjects x 1 run) and about ten minutes of idle,
which gave 36 dormant windows, all from arm moves; the simulator can add many more of both at no cost
to the lab. ``handover train`` on a lab's recordings therefore trains on the lab's cases plus
simulated ones (``PRIOR``: the paper's protocol and idle streams of the default simulator, generated
from a fixed seed at train time and cut exactly as the lab's data is cut). How much of the prior is
used is chosen among ``PRIOR.weights`` by leave-one-subject-out on the lab's subjects only: the
prior is always in the training part and never scored (``choose_weight``, the rule in ``RULE``).
A second, independent simulated idle stream gives the early rule more dormant evidence
(``evidence``): its windows are dormant cases like the lab's, split among the lab's subjects' folds.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from sklearn.base import BaseEstimator, clone

from trainer.dormant import DORMANT
from trainer.recorded_idle import DORMANT_CUT, IdleWindows, recorded_idle_windows, with_dormant

__all__ = ["PRIOR", "PriorCases", "PriorRecipe", "WithPrior", "choice_lines", "choose_weight", "evidence",
           "markdown_lines", "prior_problem", "use_prior"]


@dataclass(frozen=True)
class PriorRecipe:
    """What the prior is made of: one owner for its seed, sizes and weight candidates."""

    seed: int = 0
    """The simulation's seed (the demo's simulator-trained model is trained on this seed's protocol too)."""
    subjects: int = 5
    runs: int = 3
    """The simulated paper protocol: ``subjects`` x ``runs`` x 36 trials."""
    idle_minutes: float = 40.0
    """Simulated idle for the prior's dormant windows (cut as the lab's idle is: ``DORMANT_CUT``)."""
    evidence_minutes: float = 40.0
    """An independent simulated idle stream whose dormant windows join the lab's folds (the early rule's evidence)."""
    weights: tuple[float, ...] = (0.0, 1.0, 3.0)
    """Prior cases per lab training case (0: the lab's cases alone; capped by the prior's size)."""

    def describe(self) -> str:
        return (f"default simulator, seed {self.seed}: paper protocol {self.subjects} subjects x {self.runs} runs, "
                f"{self.idle_minutes:g} min idle (+ {self.evidence_minutes:g} min for the early rule's evidence)")


PRIOR = PriorRecipe()
PRIOR_LAB = "A"
"""The simulated lab the prior comes from (``firmware_io.sim.lab``): the default simulator's."""
RULE = ("the prior weight (prior cases per lab case) with the highest leave-one-subject-out accuracy on the lab's "
        "own cases (every lab subject held out in turn; the prior always in the training part, never scored); "
        "ties go to the larger weight")


class PriorCases:
    """The prior's cases ``X`` ``(n, C, T)``, labels and origins; shared, never copied (clone keeps it)."""

    def __init__(self, X: np.ndarray, y: np.ndarray, origin: np.ndarray, recipe: PriorRecipe = PRIOR) -> None:
        self.X, self.y, self.origin, self.recipe = X, np.asarray(y).astype(str), np.asarray(origin).astype(str), recipe

    def __deepcopy__(self, memo) -> PriorCases:
        return self

    def __len__(self) -> int:
        return len(self.y)

    def counts(self) -> dict[str, int]:
        names, n = np.unique(self.origin, return_counts=True)
        return {str(k): int(v) for k, v in zip(names, n, strict=True)}

    def sample(self, weight: float, n_lab: int, classes: set[str]) -> np.ndarray:
        """Indices of ``round(weight * n_lab)`` prior cases of ``classes`` (all when fewer), fixed by the seed."""
        pool = np.flatnonzero(np.isin(self.y, sorted(classes)))
        n = min(len(pool), round(weight * n_lab))
        if n <= 0:
            return np.zeros(0, dtype=np.int64)
        return np.sort(np.random.default_rng(self.recipe.seed).choice(pool, size=n, replace=False))

    def draw(self, weight: float, y) -> np.ndarray:
        """``sample`` for training labels ``y``: ``weight`` prior cases per case, of ``y``'s classes (the one draw
        ``WithPrior.fit``, ``PriorUse.simulated`` and train's line all mean)."""
        y = np.asarray(y).astype(str)
        return self.sample(weight, len(y), set(y.tolist()))


class WithPrior(BaseEstimator):
    """``estimator`` trained on the given cases plus ``weight`` prior cases per case (``PriorCases.sample``).

    ``fit`` returns the fitted ``estimator`` itself (not this wrapper): what is evaluated, exported and
    replayed is an ordinary model. Prior windows are cut to the given cases' length (an early head's ``p``)."""

    def __init__(self, estimator=None, prior: PriorCases | None = None, weight: float = 0.0) -> None:
        self.estimator = estimator
        self.prior = prior
        self.weight = weight

    def fit(self, X, y):
        X, y = np.asarray(X), np.asarray(y).astype(str)
        model = clone(self.estimator)
        at = self.prior.draw(self.weight, y) if self.prior is not None else []
        if not len(at):
            return model.fit(X, y)
        Xp = self.prior.X[at][:, :, :X.shape[2]]
        return model.fit(np.concatenate([X, Xp.astype(X.dtype)]), np.concatenate([y, self.prior.y[at]]))


def prior_problem(ds) -> str | None:
    """Why the prior cannot join this data set (another sensor than the simulated SDH-2), or None."""
    from firmware_io.layout import SensorLayout

    sim = SensorLayout.sdh2()
    try:
        sizes = tuple(len(sim.columns([p])) for p in ds.pads)
    except Exception:  # a pad the simulated hand does not have
        sizes = ()
    if sizes != tuple(ds.pad_sizes) or ds.layout.n_taxels != sim.n_taxels:
        return (f"the recordings' sensor ({ds.layout.n_taxels} taxels, pads {list(ds.pad_sizes)}) is not the simulated "
                "SDH-2's: trained on the lab's data alone (as with --no-prior)")
    return None


@functools.lru_cache(maxsize=4)
def _simulated(recipe: PriorRecipe) -> tuple[list, list, list]:
    """The prior's recordings (protocol, idle, evidence idle): deterministic, kept for the process."""
    from firmware_io.sim import simulate_protocol
    from firmware_io.sim.idle import simulate_idle

    protocol = simulate_protocol(seed=recipe.seed, n_subjects=recipe.subjects, runs=recipe.runs)

    def parts(minutes: float, first: int) -> list:
        n = max(1, round(minutes / 10))
        return [simulate_idle(60.0 * minutes / n, seed=recipe.seed, part=first + k) for k in range(n)]

    n_idle = max(1, round(recipe.idle_minutes / 10))
    return protocol, parts(recipe.idle_minutes, 0), parts(recipe.evidence_minutes, n_idle)


class _Cut(NamedTuple):
    """What of the lab's data set cuts the prior's idle (all ``recorded_idle_windows`` reads of it)."""

    T: int
    pads: tuple[int, ...]
    trigger: object
    pad_sizes: tuple[int, ...]
    fullscale: float
    dormant_cut: str


def _dormant_windows(recipe: PriorRecipe, name: str, ds, dormant_cut: str) -> tuple[np.ndarray, np.ndarray]:
    """Dormant windows of the prior's simulated idle (``name``: "idle" or the "evidence" stream) for ``ds``
    (its pads, T, trigger), cut as the lab's idle (``dormant_cut``: trainer.recorded_idle.DORMANT_CUTS)."""
    return _cut_windows(recipe, name, _Cut(int(ds.T), tuple(int(p) for p in ds.pads), ds.trigger,
                                           tuple(int(s) for s in ds.pad_sizes), float(ds.fullscale), dormant_cut))


@functools.lru_cache(maxsize=8)
def _cut_windows(recipe: PriorRecipe, name: str, cut: _Cut) -> tuple[np.ndarray, np.ndarray]:
    """Kept for the process, as ``_simulated`` keeps the streams: a cut runs the trigger over every frame of
    80 simulated minutes (a quarter of a train's time), the same for every train of one process with the
    same T, pads and trigger (the tests, the own_prior bench). Read-only: the callers share them."""
    _, idle, more = _simulated(recipe)
    idle = idle if name == "idle" else more
    w = recorded_idle_windows(list(idle), [f"{name}{k}" for k in range(len(idle))], cut, 0, cut.dormant_cut)
    X, origin = w.X, np.asarray([f"{name}:{o}" for o in w.origin.tolist()])
    X.flags.writeable = origin.flags.writeable = False
    return X, origin


def build_prior(ds, say: Callable[[str], None], recipe: PriorRecipe, dormant_cut: str) -> PriorCases:
    """The prior's cases for the lab's data set ``ds``: the protocol cut by ``ds``'s trigger, T and pads,
    and (when ``ds`` has a dormant class) dormant windows of the simulated idle."""
    from trainer.dataset import build_dataset

    say(f"the product's prior: simulating ({recipe.describe()}) ...")
    protocol = _simulated(recipe)[0]
    sim = build_dataset(protocol, T=ds.T, pads=list(ds.pads), trigger=ds.trigger)
    X, y, origin = [sim.X], [sim.y.astype(str)], [np.full(len(sim.y), "protocol")]
    if DORMANT in set(ds.y.tolist()):
        dx, do = _dormant_windows(recipe, "idle", ds, dormant_cut)
        X, y, origin = [*X, dx], [*y, np.full(len(dx), DORMANT)], [*origin, do]
    return PriorCases(np.concatenate(X).astype(np.float32), np.concatenate(y), np.concatenate(origin), recipe)


def evidence(ds, recipe: PriorRecipe, dormant_cut: str):
    """``ds`` plus the evidence stream's dormant windows, dealt round-robin to the lab's subjects' folds
    (so leave-one-subject-out holds each out with a subject); ``ds`` itself without a dormant class."""
    if DORMANT not in set(ds.y.tolist()):
        return ds
    idle = _simulated(recipe)[2]
    X, origin = _dormant_windows(recipe, "evidence", ds, dormant_cut)
    subjects = sorted(set(ds.groups[ds.y != DORMANT].tolist())) or sorted(set(ds.groups.tolist()))
    groups = np.asarray([subjects[k % len(subjects)] for k in range(len(X))])
    seconds = sum(r.n_frames * r.period_s() for r in idle)
    return with_dormant(ds, IdleWindows(X=X, groups=groups, origin=origin, seconds=seconds, cut="prior evidence"))


@dataclass
class PriorChoice:
    """The weight chosen and the cross-validation it was chosen by (one row per candidate)."""

    weight: float
    rows: list[dict]
    prior: PriorCases

    def to_dict(self) -> dict:
        return {"weight": self.weight, "rule": RULE, "candidates": self.rows, "recipe": self.prior.recipe.describe(),
                "prior_cases": self.prior.counts()}


def _kinds(y: np.ndarray, pred: np.ndarray) -> dict[str, float | None]:
    act = y != DORMANT
    return {"actions": float(np.mean(pred[act] == y[act])) if act.any() else None,
            "dormant": float(np.mean(pred[~act] == y[~act])) if (~act).any() else None}


def choose_weight(estimator, ds, prior: PriorCases, say: Callable[[str], None],
                  weights: Sequence[float] | None = None, n_jobs: int | None = None) -> PriorChoice:
    """Leave-one-subject-out on the lab's cases for each candidate weight; the winner by ``RULE``."""
    from trainer.evaluation import N_JOBS, loso_splits, run_splits

    weights = tuple(prior.recipe.weights if weights is None else weights)
    splits = loso_splits(ds.groups, ds.y)
    rows = []
    for w in weights:
        say(f"the product's prior: weight {w:g}, leave one lab subject out ...")
        results = run_splits(WithPrior(estimator, prior, w), ds.X, ds.y, splits, n_jobs or N_JOBS)
        y = np.concatenate([ds.y[r["test"]] for r in results]).astype(str)
        pred = np.concatenate([np.asarray(r["y_pred"]) for r in results]).astype(str)
        per = {r["name"]: float(np.mean(ds.y[r["test"]].astype(str) == np.asarray(r["y_pred"]).astype(str)))
               for r in results}
        rows.append({"weight": w, "accuracy": float(np.mean(y == pred)), **_kinds(y, pred), "per_subject": per,
                     "n_scored": len(y)})
    best = max(rows, key=lambda r: (round(r["accuracy"], 12), r["weight"]))
    return PriorChoice(float(best["weight"]), rows, prior)


def choice_lines(choice: dict | None) -> list[str]:
    """The lab's data alone against prior plus own, side by side (terminal and report)."""
    if not choice:
        return []
    if choice.get("off"):
        return [f"the product's prior: not used ({choice['off']})"]

    def pct(v: float | None) -> str:
        return "-" if v is None else f"{v:.1%}"

    lines = [f"the product's prior ({choice['recipe']}; a pool of {prior_cases_text(choice['prior_cases'])}):"]
    for r in choice["candidates"]:
        name = "lab's data alone" if r["weight"] == 0 else f"prior x{r['weight']:g} + lab"
        lines.append(f"  {name:<20} leave one lab subject out {pct(r['accuracy'])} (actions {pct(r['actions'])}, "
                     f"dormant {pct(r['dormant'])}; {r['n_scored']} lab cases scored)"
                     + ("  <- chosen" if r["weight"] == choice["weight"] else ""))
    return lines


@dataclass
class PriorUse:
    """What training uses: the estimator (wrapped when the prior joins), the cases to fit on (the lab's,
    plus the evidence windows), how to wrap another estimator (early heads) and the report's dict."""

    estimator: object
    ds: object
    report: dict
    prior: PriorCases | None = None
    weight: float = 0.0

    def wrap(self, estimator):
        return estimator if self.prior is None else WithPrior(estimator, self.prior, self.weight)

    def simulated(self, n_lab: int) -> tuple[int, dict[str, int]]:
        """What the final model's fit takes from the simulator besides the lab's first ``n_lab`` cases: the
        evidence stream's windows and the prior's sample at the chosen weight (``PriorCases.sample``, as
        ``WithPrior.fit`` draws it): (windows, dormant windows by origin)."""
        if self.prior is None:
            return 0, {}
        y = np.asarray(self.ds.y).astype(str)
        at = self.prior.draw(self.weight, y)
        dormant = np.concatenate([np.asarray(self.ds.poses)[n_lab:][y[n_lab:] == DORMANT],
                                  self.prior.origin[at][self.prior.y[at] == DORMANT]])
        names, n = np.unique(dormant.astype(str), return_counts=True)
        return len(y) - n_lab + len(at), {str(k): int(v) for k, v in zip(names, n, strict=True)}

    def counts(self, lab):
        """``lab`` (the lab's ``runtime.training_counts.TrainingCounts``) with the simulated windows beside it."""
        windows, dormant = self.simulated(lab.windows or 0)
        return replace(lab, prior=windows, prior_dormant=sum(dormant.values()))


def prior_cases_text(counts: dict[str, int]) -> str:
    """``538 protocol windows, 55 idle (arm_move 54, quiet 1)`` from ``Prior.counts()``."""
    from trainer.data_warnings import idle_kinds_text

    idle = {k: v for k, v in counts.items() if k.startswith("idle:")}
    rest = ", ".join(f"{v} {k} windows" for k, v in counts.items() if k not in idle)
    return rest + (f", {sum(idle.values())} idle ({idle_kinds_text(idle)})" if idle else "")


def use_prior(estimator, ds, say: Callable[[str], None], recipe: PriorRecipe | None = None,
              dormant_cut: str = DORMANT_CUT) -> PriorUse:
    """The prior for the lab's data set ``ds``: built, its weight chosen (``choose_weight``), the evidence added;
    the lab's data alone (and why, in ``report["off"]``) when the sensor is not the simulated SDH-2's."""
    why = prior_problem(ds)
    if why is None and len(set(np.asarray(ds.groups).tolist())) < 2:
        why = ("one lab subject: its weight is chosen by leaving a lab subject out, so it needs a second; trained on "
               "the lab's data alone (record another subject to use it)")
    if why:
        say(f"the product's prior: not used: {why}")
        return PriorUse(estimator, ds, {"off": why})
    recipe = recipe or PRIOR
    prior = build_prior(ds, say, recipe, dormant_cut)
    choice = choose_weight(estimator, ds, prior, say)
    alone = choice.weight == 0  # the lab's data alone won: the model is that candidate, no simulated window joins
    fit_on = ds if alone else evidence(ds, recipe, dormant_cut)
    report = {**choice.to_dict(), "evidence_windows": len(fit_on.y) - len(ds.y), "lab_cases": len(ds.y)}
    for line in choice_lines(report):
        say(line)
    if alone:
        return PriorUse(estimator, ds, report)
    say(f"  the final model: the lab's {len(ds.y)} cases, {report['evidence_windows']} simulated idle windows (the "
        f"early rule's evidence) and {len(prior.draw(choice.weight, fit_on.y))} cases drawn from the pool "
        f"({choice.weight:g} per case before them)")
    return PriorUse(WithPrior(estimator, prior, choice.weight), fit_on, report, prior, choice.weight)


def markdown_lines(report: dict, synthetic: bool) -> list[str]:
    """report.md's section: where the training cases came from and the choice, side by side."""
    lines = ["## The product's prior", ""]
    if report.get("off"):
        return [*lines, f"Not used: {report['off']}.", ""]
    tag = " (**synthetic**)" if synthetic else ""
    if report["weight"] == 0:
        cases = (f"the lab's {report['lab_cases']} cases alone: the lab's data alone won, so neither the prior "
                 f"({report['recipe']}) nor its evidence windows join")
    else:
        cases = (f"the lab's {report['lab_cases']} cases, {report['evidence_windows']} dormant windows of a simulated "
                 f"idle stream dealt to the lab's subjects' folds (the early rule's evidence), and the prior "
                 f"({report['recipe']}: {prior_cases_text(report['prior_cases'])}), "
                 f"{report['weight']:g} prior cases drawn per training case (the lab's and the evidence's)")
    lines += [f"Training cases: {cases} (trainer/prior.py). Chosen as {report['rule']}{tag}:", "",
              "| training | leave one lab subject out | actions | dormant | per subject |", "|---|---:|---:|---:|---|"]
    for r in report["candidates"]:
        name = "the lab's data alone" if r["weight"] == 0 else f"prior x{r['weight']:g} + the lab's"
        pct = {k: "-" if r[k] is None else f"{r[k]:.1%}" for k in ("accuracy", "actions", "dormant")}
        star = " (chosen)" if r["weight"] == report["weight"] else ""
        lines.append(f"| {name}{star} | {pct['accuracy']} | {pct['actions']} | {pct['dormant']} | "
                     + ", ".join(f"{k} {v:.1%}" for k, v in r["per_subject"].items()) + " |")
    return [*lines, ""]
