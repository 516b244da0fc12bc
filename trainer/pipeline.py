"""Training as a library: ``train(TrainOptions(...)) -> TrainResult``.

Load (or simulate) recordings, cut cases with the trigger the model will record, fit the
estimator the options name (or the one ``--select`` chooses), evaluate it as in the paper against
the hand-designed baseline, and write the report folder: report.md, metrics.json, figures,
model.joblib and model.onnx. ``handover train`` and ``handover demo`` both call :func:`train`.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from firmware_io.commands.options import PROGRESS, progress_to
from trainer.train_options import TrainOptions, build_estimator

__all__ = ["evaluate", "load_or_simulate", "progress_bar", "train"]


@dataclass
class TrainResult:
    """What one training run produced (the files are in ``out``)."""

    out: Path
    metrics: dict
    onnx_written: bool
    """False when the export was asked for and failed (the report is still written)."""
    headline: str = ""
    """The result for a terminal (``train_outputs.headline``): the command prints it, a library caller may."""

    @property
    def exit_code(self) -> int:
        return 0 if self.onnx_written else 1


def progress_bar(quiet: bool, desc: str, total: int):
    from tqdm import tqdm

    def wrap(iterable):  # bars only on a terminal: a redirected log gets no carriage-return clutter
        return tqdm(iterable, desc=desc, total=total, file=sys.stderr, disable=quiet or not sys.stderr.isatty(),
                    leave=False)

    return wrap


def load_or_simulate(data: Sequence[str] | None, seed: int, say: Callable[[str], None]
                     ) -> tuple[list, list[str], str, bool]:
    """Recordings, their names (for lines about one of them), where they came from, and whether they are
    synthetic. ``data``: folders of recordings or capture folders (``trainer.field_folder``); None: simulate."""
    if data:
        recs, names, sources = [], [], []
        for folder in data:
            got, got_names = _read_folder(folder)
            recs += got
            names += got_names if len(data) == 1 else [str(Path(folder) / n) for n in got_names]
            sources.append(f"{len(got)} recordings in {folder}")
        synthetic = any(looks_simulated(r.meta) for r in recs)
        return recs, names, ", ".join(sources), synthetic
    try:
        from firmware_io.sim import simulate_protocol
    except ImportError as exc:
        raise FileNotFoundError(f"no --data given and the simulator is not available ({exc})") from None
    say(f"simulating the paper's protocol (seed {seed}) ...")
    recs = simulate_protocol(seed=seed)
    names = [f"simulated recording {i + 1}" for i in range(len(recs))]
    return recs, names, f"simulated protocol, firmware_io.sim.simulate_protocol(seed={seed})", True


def _read_folder(folder: str) -> tuple[list, list[str]]:
    """A capture folder's confirmed events and idle (its lines seen even with --quiet), else every
    recording of the folder."""
    from firmware_io.recordings.recording import RecordingError, find_recordings, load_all
    from trainer.field_folder import field_recordings, is_capture_folder

    if is_capture_folder(folder):
        return field_recordings(folder, PROGRESS.warning)
    paths = find_recordings(folder)
    if not paths:
        raise FileNotFoundError(f"{folder}: no .hrec recordings in this folder; record some with `handover record` "
                                f"(README step 2) or import them with `handover import`")
    try:
        return load_all(paths), [p.name for p in paths]
    except RecordingError as exc:
        raise RecordingError(f"{exc}; move it out of {folder} (or record it again) and train again") from None


def looks_simulated(meta: dict) -> bool:
    """Whether a recording's metadata says it came from the simulator (anything but a real hand's signals)."""
    text = json.dumps(meta, default=str).lower()
    return bool(meta.get("synthetic")) or "simulat" in text or "synthetic" in text


def train(options: TrainOptions) -> TrainResult:
    """Train, evaluate and export as ``options`` say; raises OptionsError for options that cannot
    train, and RecordingError, DatasetError, LayoutError, OSError or ValueError for data that cannot."""
    from trainer import report
    from trainer.evaluation import tsne_embedding
    from trainer.train_outputs import headline, metrics_of, write_model

    options.check()
    t0 = time.perf_counter()
    say = progress_to(options.quiet)
    out = Path(options.out)
    out.mkdir(parents=True, exist_ok=True)
    recordings, names, source, synthetic = load_or_simulate(options.data, options.seed, say)
    ds, idle = _cases(options, recordings, names, say)
    selection = None
    if options.select:
        from trainer.select import select_model

        selection = select_model(ds, options, say=say)
        estimator = selection.estimator
    else:
        estimator = build_estimator(options, ds)
    lab, prior = ds, None
    if options.prior and options.data:
        from trainer.prior import use_prior

        prior = use_prior(estimator, ds, say, dormant_cut=options.dormant_cut)
        estimator, ds = prior.estimator, prior.ds  # the lab's cases (+ the evidence windows) and the prior
    notes = _data_notes(options, recordings, names, idle, prior, len(lab.y))
    say("training the final model on all cases ...")
    model = _fit_final(estimator, ds)
    evaluation = evaluate(options, lab, estimator, say)  # scored on the lab's own cases only
    heads, early_metrics = fit_early_heads(options, with_actions(ds), estimator, say,
                                           wrap=prior.wrap if prior else None)
    sweep = None
    if not options.no_sweep and "bow" in options.families:
        sweep = _sweeps(options, recordings, out, say)
    elif not options.no_sweep:  # K and W are the BoW family's; its sweep says nothing about this model
        say(f"no codebook sweep: it measures the paper's Bag-of-Words features, and this model uses "
            f"{'+'.join(options.families)} (`handover sweep` runs it on its own)")
    say(f"t-SNE of the {report.features_label(getattr(model, 'families', ('bow',)))} ...")
    embedding = tsne_embedding(model.transform_histograms(ds.X), seed=options.seed)
    replay = None
    if options.replay:
        from trainer.own_replay import held_out_replay

        say("replaying each held-out subject's recording through the daemon ...")
        replay = held_out_replay(ds, estimator, recordings, names, say, heads_of=heads.folds if heads else None)
    metrics = metrics_of(options, lab, model, evaluation, sweep, selection, source=source, synthetic=synthetic)
    metrics["prior"] = prior.report if prior else None
    metrics |= prior.counts(lab.counts()).to_meta() if prior else {}  # what came from the simulator, beside the lab's
    metrics["idle"] = idle and {"seconds": round(idle.seconds, 1), "dormant_windows": len(idle.X),
                                "dormant_class": idle.makes_class, "per_origin": idle.per_source,
                                "notes": idle.notes, "cut": idle.cut}
    metrics["own_replay"] = replay
    metrics["data_notes"], metrics["partial_subjects"] = notes.lines, notes.partial
    if early_metrics is not None:
        metrics["early"] = early_metrics
    onnx_ok = write_model(options, lab, model, metrics, out, early=heads)
    if onnx_ok and not options.no_onnx and options.replay and scores_real_idle(options.real_idle, synthetic):
        from runtime.model import load_model
        from trainer.own_replay import real_idle
        from trainer.shared_data import default_data_dir

        say(f"replaying the real recordings without a handover in {default_data_dir()} through the daemon ...")
        metrics["real_idle"] = real_idle(load_model(out / "model.onnx", warm_up=False), default_data_dir(), say)
    say("writing figures and the report ...")
    metrics["seconds"] = round(time.perf_counter() - t0, 1)
    _write_report(options, out, ds, embedding, metrics, selection, synthetic)
    return TrainResult(out, metrics, onnx_ok, headline(metrics, out, onnx_written=onnx_ok and not options.no_onnx))


def _data_notes(options: TrainOptions, recordings: list, names: list[str], idle, prior, n_lab: int):
    """What the data can carry (trainer.data_warnings), on the console even with --quiet; the dormant class
    counted with the prior's simulated windows beside the lab's (``prior``: a ``trainer.prior.PriorUse``)."""
    from trainer.data_warnings import data_notes
    from trainer.prior import PRIOR_LAB

    notes = data_notes(recordings, names, idle, prior_lab=PRIOR_LAB if options.prior and options.data else None,
                       prior_dormant=prior.simulated(n_lab)[1] if prior else None)
    for line in notes.lines:
        PROGRESS.warning(f"handover train: {line}")
    return notes


def _fit_final(estimator, ds):
    """The exported model on all cases. A final fit that stopped at the SVM's iteration cap
    (trainer.classifier.MAX_ITER) says so in one line, seen even with --quiet, instead of a Python warning;
    report.md lists every capped fit, the search's candidates too."""
    import warnings

    from sklearn.exceptions import ConvergenceWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        model = estimator.fit(ds.X, ds.y)
    for w in caught:
        if issubclass(w.category, ConvergenceWarning):
            PROGRESS.warning(f"handover train: {w.message}")
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return model


def _cases(options: TrainOptions, recordings: list, names: list[str], say: Callable[[str], None]):
    """The dataset training cuts from the recordings (with the recorded idle as the dormant class when asked),
    or DatasetError for recordings that give too few cases."""
    import numpy as np

    from trainer.dataset import DatasetError, build_dataset, dataset_trigger, untriggered_lines
    from trainer.dormant import DORMANT
    from trainer.recorded_idle import add_idle, idle_only_problem

    problem = idle_only_problem(recordings, names)
    if problem:
        raise DatasetError(problem)
    ds = build_dataset(recordings, T=options.T, pads=options.pads,
                       trigger=dataset_trigger(options.trigger, options.fraction))
    say(ds.counts().text())
    for line in untriggered_lines(ds):  # the trials that gave no window, with their reasons
        say(f"  {line}")
    if n := int(np.sum(ds.y == DORMANT)) - ds.counts().dormant:  # counts: the dormant windows cut from idle
        say(f"{n} dormant case{'s' if n != 1 else ''} from the field: captured events a person labelled dormant "
            "(handover review)")
    idle = None
    if options.dormant and options.data:  # lines about problems in the user's idle data are seen even with --quiet
        ds, idle = add_idle(ds, recordings, names, options.seed, say, cut=options.dormant_cut, warn=PROGRESS.warning)
    problem = too_few_cases(ds)  # counted with the idle's dormant windows: they are cases like any other
    if problem:
        raise DatasetError(problem)
    return ds, idle


def _write_report(options: TrainOptions, out: Path, ds, embedding, metrics: dict, selection, synthetic: bool) -> None:
    """Figures, metrics.json and report.md (with the selection's and the early heads' sections when there)."""
    from trainer import report
    from trainer.train_outputs import figures

    early_metrics = metrics.get("early")
    shown = figures(options, ds, embedding, metrics, out)
    if early_metrics and not early_metrics.get("skipped"):
        from trainer.early_report import plot_curve

        shown["Early decisions: accuracy against frames, per class, the rule's operating point starred"] = \
            plot_curve(early_metrics, out / "early_curve.png", synthetic).name
    metrics["command"] = options.command_line()
    report.write_metrics(out, metrics)
    md_path = report.write_markdown(out, metrics, metrics["command"], shown)
    if selection is not None:
        from trainer.select import markdown_lines

        md_path.write_text(md_path.read_text() + "\n".join(markdown_lines(selection)) + "\n")
    if metrics.get("prior"):
        from trainer.prior import markdown_lines as prior_lines

        md_path.write_text(md_path.read_text() + "\n" + "\n".join(prior_lines(metrics["prior"], synthetic)) + "\n")
    if early_metrics is not None:
        from trainer.early_report import markdown_lines as early_lines

        md_path.write_text(md_path.read_text() + "\n" + "\n".join(early_lines(early_metrics, synthetic)) + "\n")


def scores_real_idle(asked: bool | None, synthetic: bool) -> bool:
    """Whether to replay the real recordings without a handover (../shared/data) through the model:
    when asked, else for a model trained on real recordings where the folder is present (a minute)."""
    from trainer.shared_data import default_data_dir

    if asked is False:
        return False
    return default_data_dir().is_dir() and (asked is True or not synthetic)


def with_actions(ds):
    """The data set without groups that hold no action (an idle-only recording's dormant windows): a
    leave-groups-out fit on those alone would hold one class."""
    import numpy as np

    from trainer.dormant import DORMANT

    acting = {g for g, y in zip(ds.groups.tolist(), ds.y.tolist(), strict=True) if y != DORMANT}
    keep = np.isin(ds.groups, sorted(acting))
    return ds if keep.all() else ds.subset(np.flatnonzero(keep))


def fit_early_heads(options: TrainOptions, ds, estimator, say: Callable[[str], None],
                    wrap: Callable | None = None) -> tuple[Any, dict | None]:
    """Early heads and their rule (trainer.early) with the nested evaluation for the report, or
    (None, None) with ``--early off``; (None, {"skipped": why}) when the data cannot choose a rule.
    ``wrap``: turns a head into one trained with the prior (trainer.prior). The heads' ``folds`` are the
    nested evaluation's heads and rule without each subject, for the held-out replay."""
    if options.early == "off":
        return None, None
    import numpy as np
    from sklearn.base import clone

    from trainer import early

    points = [p for p in early.EARLY_POINTS if p < options.T]
    why = (f"T={options.T} leaves no early point" if not points else
           "early heads need at least three subjects (a rule chosen inside each training part)"
           if len(set(ds.groups.tolist())) < 3 else early.part_problem(ds.groups, ds.y))
    if why:
        say(f"early decisions skipped: {why}")
        return None, {"skipped": why}
    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    base = early.head_factory(ds.pad_sizes, shapes, options.seed, ds.fullscale)

    def make(p: int):
        return wrap(base(p)) if wrap else base(p)

    def make_full(_frames: int):
        return clone(estimator)

    fits = early.Fits(ds.X, ds.y, ds.groups, points, make, make_full)
    fits.per_class = True  # a lab's model: the rule may keep a class whose early answers cost false events for T
    ev = early.evaluate(fits, say=say)
    say("early decisions: heads and rule on all training cases ...")
    heads = early.fit_early(ds.X, ds.y, ds.groups, make, make_full, points, fits=fits)
    ev["rule"] = heads.spec.to_meta()
    ev["rule_inner"] = {"accuracy": heads.choice.accuracy, "full_accuracy": heads.choice.full_accuracy,
                        "mean_frames": heads.choice.mean_frames}
    ev["n_subjects"] = len(np.unique(ds.groups))
    heads.folds = early.fold_heads(fits, ev["rules"])
    return heads, ev


MIN_CASES, MIN_CLASSES = 10, 2
"""Fewer triggered cases or classes than this cannot train (nor be split for evaluation)."""


def too_few_cases(ds) -> str | None:
    """None, or one line: the triggered cases per class, the trials per class that never triggered and
    why, and the likely cause for the trigger that cut them."""
    from collections import Counter

    from trainer.dataset import reason_counts

    cases = Counter(ds.y.tolist())
    if len(cases) >= MIN_CLASSES and len(ds.y) >= MIN_CASES:
        return _split_problem(cases)
    missed = Counter(s.action for s in ds.untriggered)
    why = reason_counts(ds.untriggered)
    text = (f"only {len(ds.y)} triggered cases of {len(cases)} class{'es' if len(cases) != 1 else ''} "
            f"({_counts(cases) or 'none'}): too few to train (at least {MIN_CASES} cases of {MIN_CLASSES} classes)")
    if missed:
        first = ds.untriggered[0]
        text += (f"; {sum(missed.values())} trials gave no case ({_counts(missed)}): {_counts(why)} "
                 f"(e.g. {first.action}: {first.reason})")
    if ds.trigger.kind == "onset":
        return text + ("; trials must start from the settled grasp: the onset trigger takes each trial's first "
                       "frame as the baseline and fires when a pad departs from it (pulls lower the pressure), "
                       "so check where the trials start, or try --trigger threshold")
    return text + (f"; the threshold trigger needs a rising edge to {ds.fraction:g} x full scale, and pulls lower "
                   "the pressure: try --trigger onset or a lower --fraction")


def _split_problem(cases) -> str | None:
    """Enough cases to train, too few for the evaluation's stratified split (each class on both sides):
    said in the trainer's words, not the splitter's."""
    import math

    from trainer.evaluation import POOLED_TEST_SIZE

    n, k = sum(cases.values()), len(cases)
    test = math.ceil(POOLED_TEST_SIZE * n)
    if test >= k and n - test >= k and min(cases.values()) >= 2:
        return None
    return (f"only {n} triggered cases of {k} classes ({_counts(cases)}): the evaluation's stratified "
            f"{POOLED_TEST_SIZE:.0%} test split needs each class at least twice and {k} cases on each side "
            f"(about {math.ceil((k - 1) / POOLED_TEST_SIZE) + 1} cases); " + _short_advice(cases))


def _short_advice(cases) -> str:
    """What to record: for the classes with fewer than two cases, by name (dormant comes from idle)."""
    from trainer.data_warnings import MORE_IDLE
    from trainer.dormant import DORMANT

    short = sorted(c for c, n in cases.items() if n < 2)
    actions = [c for c in short if c != DORMANT]
    said = []
    if actions:
        said.append(f"record more runs of {', '.join(actions)} (handover record --runs)")
    if DORMANT in short:
        said.append(f"dormant is short: record idle ({MORE_IDLE}) or label more captured events dormant "
                    "(handover review)")
    return "; ".join(said) or "record more runs of each action (handover record --runs)"


def _counts(counter) -> str:
    return ", ".join(f"{name} {n}" for name, n in sorted(counter.items()))


def evaluate(options: TrainOptions, ds, estimator, say: Callable[[str], None]) -> dict[str, Any]:
    """The paper's two configurations for the estimator and the hand-designed baseline; with one
    subject only configuration 1 (``config2`` entries None, ``loso_unavailable`` says why)."""
    from trainer.baseline import BaselineSVC
    from trainer.evaluation import config1, config2, loso_skipped, loso_unavailable

    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    base = BaselineSVC(pad_shapes=shapes, kernel="rbf")
    seeds = list(range(options.seed, options.seed + options.repeats))
    n_subjects = len(set(ds.groups.tolist()))
    missing = loso_unavailable(ds.groups, ds.y)
    if missing:  # a warning the user must see even with --quiet: the model is trained, LOSO is not measured
        PROGRESS.warning(f"handover train: {missing}")
    else:  # folds whose training part has one class are skipped, never silently
        for why in loso_skipped(ds.groups, ds.y).values():
            PROGRESS.warning(f"handover train: {why}; that fold is skipped")
    say(f"evaluating (configuration 1, {'' if missing else 'leave one subject out, '}baseline) ...")
    q = options.quiet
    name = "+".join(options.families) if options.families != ("bow",) else "BoW"
    result: dict[str, Any] = {
        "config1": config1(estimator, ds.X, ds.y, seeds=seeds, progress=progress_bar(q, f"config 1 ({name})", len(seeds))),
        "config2": None if missing else config2(estimator, ds.X, ds.y, ds.groups,
                                                progress=progress_bar(q, f"LOSO ({name})", n_subjects)),
        "baseline_config1": config1(base, ds.X, ds.y, seeds=seeds,
                                    progress=progress_bar(q, "config 1 (baseline)", len(seeds))),
        "baseline_config2": None if missing else config2(base, ds.X, ds.y, ds.groups,
                                                         progress=progress_bar(q, "LOSO (baseline)", n_subjects)),
    }
    return {**result, "loso_unavailable": missing} if missing else result


def _sweeps(options: TrainOptions, recordings, out: Path, say: Callable[[str], None]) -> dict | None:
    from trainer.sweeps import QUICK_K, QUICK_T, QUICK_W, run_sweeps

    path = Path(options.sweep_file) if options.sweep_file else out / "sweep.json"
    if path.is_file():
        say(f"sweep results from {path}")
        try:
            return json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise FileNotFoundError(f"{path}: not a sweep result ({exc})") from None
    if options.sweep_file:
        raise FileNotFoundError(f"{path}: no such sweep result")
    base = {"K": options.K, "W": options.W, "T": options.T, "seed": options.seed, "per_pad": options.per_pad}
    seeds = (options.seed, options.seed + 1)
    n = len(QUICK_K) + len(QUICK_W) + len(QUICK_T)
    say("small built-in sweep of K, W, T (`handover sweep` runs the full one) ...")
    result = run_sweeps(recordings, base, QUICK_K, QUICK_W, QUICK_T, [options.svm_kernel], options.pads,
                        options.fraction, mode="config1", seeds=seeds, progress=progress_bar(options.quiet, "sweep", n))
    result["description"] = "Small built-in sweep. " + result["description"]
    return result
