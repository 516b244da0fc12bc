"""Side-by-side comparison on real SDH-2 recordings and the simulated protocol (synthetic): the
shipped default, the paper's BoW + SVM, the feature families of ``trainer.features``, the
hand-designed baseline, a flattened-series SVM and aeon's MiniRocket.

Tasks (each model is trained and tested on the same splits): the real tasks of
``trainer.real_tasks`` (each with its split written down) and the simulated protocol, leave one
subject out.

Latency: every ONNX model, trained on all simulated cases, is exported and run one case at a time
through ``runtime.model.load_model`` (1 thread, spinning off): median and p99 of wall time, and p99
of the calling thread's CPU time (what the graph costs without the shared machine's other work).
MiniRocket has no ONNX graph: its aeon ``predict`` of one case is timed instead and marked so.

The shipped default is chosen by ``trainer.default_choice`` (nested cross-validation: the outer
test folds reported here never enter the choice).
"""

from __future__ import annotations

import os
import platform
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin

from trainer.real_tasks import CHUNK_FRAMES, CONTACT_FRACTION, FULLSCALE, STRIDE, RealTask, T, cut_windows  # noqa: F401

__all__ = ["MiniRocketCases", "done_check", "markdown", "pareto_front", "plot", "run"]


@dataclass(frozen=True)
class ModelSpec:
    name: str
    kind: str  # bow, flat, features, default, minirocket
    params: dict
    description: str
    flags: str = ""
    """``handover train`` flags that produce it."""
    candidate: str | None = None
    """Its name among the candidates of ``handover train --select`` (trainer.select), if it is one."""


ONNX_KINDS = ("bow", "flat", "features", "default")
DIAGNOSES = {"real_slip": "its former single split (first 60 % of each file's chunks train, the rest test), where the "
                          "default lost on one test chunk, and why, judged on the training part only: "
                          "results/slip_diagnosis.md"}
"""Where a task's verdict is examined."""


def model_specs(quick: bool, minirocket: bool = True) -> list[ModelSpec]:
    """The compared models: the shipped default first, the references, then the paper and the families."""
    from trainer.defaults import default_candidate_name
    from trainer.select import ROCKET_SETTINGS

    default_desc = f"what `handover train` exports without options: {default_candidate_name()} (trainer/defaults.py)"
    specs = [
        ModelSpec("default", "default", {}, default_desc, ""),
        ModelSpec("baseline", "features", {"families": ("hand",), "kernel": "rbf"},
                  "hand-designed features (14 per pad) + SVM, as one ONNX graph", "--features hand --kernel rbf",
                  "hand rbf"),
        ModelSpec("flat-svm", "flat", {}, "flattened C x T window, standardised, SVM"),
        ModelSpec("paper", "bow", {"kernel": "rbf"}, "paper: K=10, W=7, one histogram, hard words, RBF",
                  "--no-per-pad --kernel rbf"),
        ModelSpec("per-pad", "bow", {"per_pad": True, "kernel": "linear"},
                  "paper + one histogram per pad, linear (the previous default)", "--features bow",
                  "bow per-pad linear"),
        ModelSpec("levels", "bow", {"per_pad": True, "level_features": True, "scale_features": True},
                  "per pad + level features, standardised", "--per-pad --level-features --scale-features"),
        ModelSpec("stats", "features", {"families": ("stats",), "kernel": "rbf"},
                  "per-pad level statistics (pressure, area, centre of pressure: mean, std, change; peak)",
                  "--features stats --kernel rbf", "stats rbf"),
        ModelSpec("stats+bow", "features", {"families": ("stats", "bow"), "kernel": "rbf"},
                  "level statistics + per-pad BoW", "--features stats,bow --kernel rbf", "stats+bow rbf"),
        ModelSpec("hand+stats", "features", {"families": ("hand", "stats"), "kernel": "rbf"},
                  "hand-designed + level statistics", "--features hand,stats --kernel rbf", "hand+stats rbf"),
        ModelSpec("hand+stats distinct", "features",
                  {"families": ("hand", "stats"), "kernel": "rbf", "feature_weighting": "distinct"},
                  "hand-designed + level statistics, a quantity both compute counted once in the distance",
                  "--features hand,stats --kernel rbf --feature-weighting distinct", "hand+stats rbf distinct"),
        ModelSpec("rocket+stats", "features", {"families": ("rocket", "stats"), "kernel": "linear", **ROCKET_SETTINGS},
                  "MiniRocket-style PPV of per-pad signals (Conv, dilations 1, 2) + level statistics, linear SVM C=1",
                  "--features rocket,stats --kernel linear --C 1", "rocket+stats linear"),
        ModelSpec("hand+stats linear distinct", "features",
                  {"families": ("hand", "stats"), "kernel": "linear", "feature_weighting": "distinct"},
                  "hand-designed + level statistics, counted once, linear SVM (C searched)",
                  "--features hand,stats --kernel linear --feature-weighting distinct", "hand+stats linear distinct"),
        ModelSpec("rocket+hand+stats", "features",
                  {"families": ("rocket", "hand", "stats"), "kernel": "linear", **ROCKET_SETTINGS},
                  "MiniRocket-style PPV + hand-designed + level statistics, linear SVM C=1",
                  "--features rocket,hand,stats --kernel linear --C 1", "rocket+hand+stats linear"),
    ]
    if quick:
        specs = [s for s in specs if s.name in ("default", "paper", "baseline", "flat-svm", "stats")]
    if minirocket:
        specs.append(ModelSpec("minirocket", "minirocket", {"n_kernels": 500 if quick else 2000},
                               "aeon MiniRocket + ridge (reference, no ONNX)"))
    return specs


class MiniRocketCases(ClassifierMixin, BaseEstimator):
    """aeon's MiniRocketClassifier on float64 cases (aeon imported only when fitted)."""

    def __init__(self, n_kernels: int = 2000, random_state: int = 0):
        self.n_kernels = n_kernels
        self.random_state = random_state

    def fit(self, X, y):
        from aeon.classification.convolution_based import MiniRocketClassifier

        self.inner_ = MiniRocketClassifier(n_kernels=self.n_kernels, random_state=self.random_state, n_jobs=1)
        self.inner_.fit(np.asarray(X, dtype=np.float64), np.asarray(y))
        self.classes_ = self.inner_.classes_
        return self

    def predict(self, X):
        return self.inner_.predict(np.asarray(X, dtype=np.float64))


def make_estimator(spec: ModelSpec, pad_sizes: tuple[int, ...], pad_shapes: list[tuple[int, int]], seed: int = 0):
    if spec.kind == "default":
        from trainer.defaults import default_classifier

        return default_classifier(pad_sizes, pad_shapes=pad_shapes, random_state=seed)
    if spec.kind == "features":
        from trainer.feature_svc import FeatureSVC

        return FeatureSVC(pad_sizes=pad_sizes, pad_shapes=pad_shapes, random_state=seed, **spec.params)
    if spec.kind == "bow":
        from trainer.defaults import paper_classifier

        return paper_classifier(pad_sizes, seed, **spec.params)
    if spec.kind == "flat":
        from trainer.flat import FlatSVC

        return FlatSVC(**spec.params)
    if spec.kind == "minirocket":
        return MiniRocketCases(random_state=seed, **spec.params)
    raise ValueError(f"unknown model kind {spec.kind!r}")


# -- evaluation --------------------------------------------------------------------------------------
def evaluate_simulated(specs, ds, n_jobs: int, say: Callable[[str], None]) -> dict:
    """Leave one subject out on the simulated protocol (synthetic; configuration 1, pooled 80/20, is in
    the ``handover train`` reports)."""
    from trainer.evaluation import config2

    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    out = {}
    for spec in specs:
        t0 = time.perf_counter()
        est = make_estimator(spec, tuple(ds.pad_sizes), shapes)
        c2 = config2(est, ds.X, ds.y, ds.groups, n_jobs=n_jobs)
        out[spec.name] = {"loso_accuracy": c2["accuracy"], "loso_per_subject": c2["per_subject"],
                          "loso_subject_std": c2["subject_std"],
                          "seconds": round(time.perf_counter() - t0, 1)}
        say(f"  simulated {spec.name}: LOSO {c2['accuracy']:.3f} "
            f"({out[spec.name]['seconds']:.0f} s)")
    return out


def evaluate_real(specs, task: RealTask, n_jobs: int, say: Callable[[str], None]) -> dict:
    from trainer.evaluation import run_splits

    out = {}
    for spec in specs:
        t0 = time.perf_counter()
        est = make_estimator(spec, task.pad_sizes, task.pad_shapes)
        try:
            results = run_splits(est, task.X, task.y, task.splits, n_jobs=n_jobs)
        except ValueError as exc:
            out[spec.name] = {"error": str(exc)}
            say(f"  {task.name} {spec.name}: failed ({exc})")
            continue
        accs = {r["name"]: float(np.mean(task.y[r["test"]] == r["y_pred"])) for r in results}
        pooled = float(np.mean(np.concatenate([task.y[r["test"]] == r["y_pred"] for r in results])))
        out[spec.name] = {"accuracy": pooled, "per_split": accs, "seconds": round(time.perf_counter() - t0, 1)}
        say(f"  {task.name} {spec.name}: {pooled:.3f} ({out[spec.name]['seconds']:.0f} s)")
    return out


def time_single_case(specs, ds, folder: Path, repeats: int, seed: int, say) -> dict:
    """Single-case latency of a model trained on all simulated cases: ONNX through the runtime's
    loader (1 thread) where the model exports, else the Python predict (marked)."""
    from threadpoolctl import threadpool_limits

    from runtime.model import load_model
    from trainer.measure import cycling, export_metadata, percentiles, time_calls
    from trainer.onnx_export import export_onnx

    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, len(ds.X), size=64)
    frames = np.ascontiguousarray(ds.X[pick].transpose(0, 2, 1), dtype=np.float32)
    out = {}
    for spec in specs:
        with threadpool_limits(1):
            model = make_estimator(spec, tuple(ds.pad_sizes), shapes).fit(ds.X, ds.y)
            entry: dict = {}
            if spec.kind in ONNX_KINDS:
                path = export_onnx(model, folder / f"{spec.name}.onnx", export_metadata(ds, model, seed=seed))
                loaded = load_model(path)
                entry["engine"] = "onnxruntime (runtime.model.load_model, 1 thread)"
                entry["model_bytes"] = path.stat().st_size
                one = [frames[i : i + 1] for i in range(len(frames))]
                stats = percentiles(time_calls(cycling(loaded.run, one), repeats))
                cpu = percentiles(time_calls(cycling(loaded.run, one), repeats, cpu=True))
                entry.update(cpu_p50_us=cpu["p50"], cpu_p99_us=cpu["p99"])
            else:
                entry["engine"] = "python predict (no ONNX graph)"
                cases = [ds.X[i : i + 1] for i in pick]
                stats = percentiles(time_calls(cycling(model.predict, cases), max(20, repeats // 10), warmup=5))
        entry.update(p50_us=stats["p50"], p99_us=stats["p99"], n=stats["n"])
        out[spec.name] = entry
        say(f"  latency {spec.name}: median {stats['p50']:.0f} us, p99 {stats['p99']:.0f} us, CPU p99 "
            f"{entry.get('cpu_p99_us') or float('nan'):.0f} us ({entry['engine']})")
    return out


def pareto_front(points: dict[str, tuple[float, float]]) -> list[str]:
    """Names not dominated in (higher accuracy, lower latency)."""
    front = []
    for name, (acc, lat) in points.items():
        if not any(a >= acc and t <= lat and (a > acc or t < lat) for o, (a, t) in points.items() if o != name):
            front.append(name)
    return front


def recommend(specs, tasks, ds, latency: dict, n_jobs: int, say) -> dict:
    """The shipped default by the rule of ``trainer.default_choice`` (nested CV, never a test fold),
    with the latency of the candidates' exported graphs (CPU time p99: the shared machine's other
    work must not decide) and whether ``trainer.defaults`` ships that choice."""
    from trainer.default_choice import choose_default
    from trainer.defaults import default_candidate_name

    lat = {s.candidate: {"p50_us": latency[s.name]["cpu_p50_us"], "p99_us": latency[s.name]["cpu_p99_us"],
                         "model": s.name} for s in specs if s.candidate}
    choice = choose_default(tasks, ds, lat, n_jobs, say)
    chosen = next((s for s in specs if s.candidate == choice["chosen"]), None)
    shipped = default_candidate_name()
    choice.update(model=chosen.name if chosen else None, flags=chosen.flags if chosen else "",
                  shipped=shipped, shipped_matches=bool(chosen) and choice["chosen"] == shipped)
    return choice


def run(quick: bool, seed: int, n_jobs: int, data_dir: Path | None, minirocket: bool, say) -> dict:
    from trainer.dataset import build_dataset
    from trainer.measure import load_average, machine_info, simulated_protocol

    t0 = time.perf_counter()
    load_before = load_average()  # machine_info() below is taken at the end
    specs = model_specs(quick, minirocket)
    say("simulated protocol (synthetic) ...")
    ds = build_dataset(list(simulated_protocol(seed=seed, quick=quick)), T=T, pads="all")
    sim = evaluate_simulated(specs, ds, n_jobs, say)
    real, notes, tasks = {}, [], []
    if data_dir is None:
        notes.append("real recordings not evaluated (--no-real)")
    elif not (Path(data_dir) / "sdh2-dsa").is_dir():
        notes.append(f"real recordings skipped: {Path(data_dir) / 'sdh2-dsa'} not found")
    else:
        from trainer.real_tasks import real_tasks

        tasks, notes = real_tasks(Path(data_dir), seed)
        for task in tasks:
            say(f"{task.name}: {len(task.y)} windows, classes {sorted(set(task.y.tolist()))} ...")
            counts = {c: int((task.y == c).sum()) for c in sorted(set(task.y.tolist()))}
            real[task.name] = {"description": task.description, "split": task.split_rule, "n_windows": len(task.y),
                               "n_chunks": len(set(task.chunks.tolist())), "windows_per_class": counts,
                               "n_channels": int(task.X.shape[1]),
                               "results": evaluate_real(specs, task, n_jobs, say)}
    say("single-case latency ...")
    with tempfile.TemporaryDirectory(prefix="handover-compare-") as tmp:
        latency = time_single_case(specs, ds, Path(tmp), 300 if quick else 3000, seed, say)
    return {
        "synthetic_simulated": True,
        "load_before": load_before,
        "quick": quick,
        "seed": seed,
        "T": T,
        "window_rule": {"stride": STRIDE, "chunk_frames": CHUNK_FRAMES, "contact_fraction": CONTACT_FRACTION},
        "n_simulated_cases": len(ds.y),
        "n_channels_simulated": int(ds.X.shape[1]),
        "models": [{"name": s.name, "kind": s.kind, "description": s.description, "train_flags": s.flags,
                    "params": {k: list(v) if isinstance(v, tuple) else v for k, v in s.params.items()}} for s in specs],
        "simulated": sim,
        "real": real,
        "notes": notes,
        "latency": latency,
        "recommendation": recommend(specs, tasks, ds, latency, n_jobs, say),
        "seconds": round(time.perf_counter() - t0, 1),
        "machine": {**machine_info(), "node": platform.node()},
        "cpu_count": os.cpu_count(),
    }


# -- report ------------------------------------------------------------------------------------------
def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def _cell(entry: dict | None) -> str:
    """Pooled accuracy, with the std over outer splits where there are several."""
    if not entry or entry.get("accuracy") is None:
        return "-"
    spread = fold_spread(entry)
    return _pct(entry["accuracy"]) + (f" +/- {100 * spread:.1f}" if spread is not None else "")


def fold_spread(entry: dict) -> float | None:
    splits = list((entry.get("per_split") or {}).values())
    return float(np.std(splits, ddof=1)) if len(splits) > 1 else None


REFERENCES = ("minirocket", "flat-svm", "baseline")


def done_check(res: dict) -> list[str]:
    """Per real task: the default against the best of the references, within their fold spread?"""
    lines = []
    for t, r in res["real"].items():
        got = r["results"].get("default", {}).get("accuracy")
        refs = {n: r["results"][n] for n in REFERENCES if r["results"].get(n, {}).get("accuracy") is not None}
        if got is None or not refs:
            continue
        best = max(refs, key=lambda n: refs[n]["accuracy"])
        spread = fold_spread(refs[best])
        acc = refs[best]["accuracy"]
        if got >= acc:
            verdict = "at or above"
        elif spread is not None and acc - got <= spread:
            verdict = f"below, within its fold spread ({100 * spread:.1f})"
        else:
            verdict = "below, outside the spread" + ("" if spread is not None else " (one split: no spread)")
        lines.append(f"- {t}: default {_pct(got)} vs best reference {best} {_pct(acc)}: {verdict}")
    return lines


def markdown(res: dict) -> list[str]:
    real_names = list(res["real"])
    rec = res["recommendation"]
    lines = [
        "# Side-by-side comparison" + (" (quick)" if res["quick"] else ""),
        "",
        "Real = SDH-2 recordings of other projects (GPL-3.0, read from ../shared/data, labels by file); simulated "
        "protocol = the simulated hand (**synthetic data**). Accuracy in % (+/- std over the outer splits where "
        "a task has several); single-case latency in us (wall time; CPU = the calling thread's CPU time).",
        "",
        "| model | description | " + " | ".join(real_names) + " | sim. LOSO (synthetic)"
        " | latency median | latency p99 | CPU p99 | engine |",
        "|---|---|" + "---|" * len(real_names) + "---|---|---|---|---|",
    ]
    for m in res["models"]:
        n = m["name"]
        s = res["simulated"][n]
        lat = res["latency"][n]
        reals = [_cell(res["real"][t]["results"].get(n)) for t in real_names]
        name = f"**{n}**" if n == "default" else n
        lines.append(f"| {name} | {m['description']} | " + " | ".join(reals)
                     + f" | {_pct(s['loso_accuracy'])} +/- {100 * s['loso_subject_std']:.1f} | {lat['p50_us']:.0f} | "
                     f"{lat['p99_us']:.0f} | {fmt_cpu(lat)} | {lat['engine']} |")
    lines += ["", "LOSO +/- is the spread over held-out subjects (configuration 1, pooled 80/20, is in the "
              "`handover train` reports).", "", "## Real tasks", ""]
    for t, r in res["real"].items():
        lines.append(f"- **{t}**: {r['description']}; {r['n_windows']} windows in {r['n_chunks']} contact chunks, "
                     f"{r['n_channels']} taxels; split: {r['split']}; windows per class {r['windows_per_class']}.")
    for note in res["notes"]:
        lines.append(f"- {note}")
    wr = res["window_rule"]
    lines += ["", f"Window rule: T = {res['T']} frames every {wr['stride']} frames inside contact (a taxel at "
              f">= {100 * wr['contact_fraction']:.0f} % of full scale), contact runs cut into chunks of at most "
              f"{wr['chunk_frames']} frames, windows never cross a chunk, a chunk is all train or all test "
              "(trainer/real_tasks.py explains why files cannot be kept apart where one file holds one class).",
              "", "## The default against the references (real tasks)", "", *done_check(res),
              *[f"- {t}: {why}" for t, why in DIAGNOSES.items() if t in res["real"]],
              "", "## Choosing the default", "", f"Rule (trainer/default_choice.py): {rec['rule']}.", ""]
    lines += choice_lines(rec)
    lines += ["", "Figure: compare.png (simulated LOSO accuracy against single-case latency).", "",
              f"Ran in {res['seconds']:.0f} s."]
    return lines


def fmt_cpu(lat: dict) -> str:
    return "-" if lat.get("cpu_p99_us") is None else f"{lat['cpu_p99_us']:.0f}"


def choice_lines(rec: dict) -> list[str]:
    rows = rec["rows"]
    lines = ["| candidate | compare row | real inner score | ties the best | " + " | ".join(
                 next(iter(rows.values()))["real_inner"]) + " | sim. inner LOSO | CPU p50 | CPU p99 |",
             "|---|---|---|---|" + "---|" * len(next(iter(rows.values()))["real_inner"]) + "---|---|---|"] if rows else []
    for name, r in rows.items():
        sim = _pct(r["sim_inner"]) if "sim_inner" in r else "not needed"
        tie = {True: "yes", False: "no"}.get(r.get("ties_best"), "-")
        lines.append(f"| {name} | {r['model']} | {_pct(r['real_score'])} | {tie} | "
                     + " | ".join(_pct(v) for v in r["real_inner"].values())
                     + f" | {sim} | {r['p50_us']:.0f} | {r['p99_us']:.0f} |")
    scored = [n for n in rows if "ties_best" in rows[n]]
    if scored:
        from trainer.default_choice import score_order

        top = min(scored, key=lambda n: score_order(rows[n]["real_score"], rows[n]["p50_us"]))
        lines += ["", f"Ties (the one-standard-error rule, trainer/default_choice.py `ties`) are new on 2026-11-24: "
                  f"before, only equal scores at 3 decimals tied, and that rule would put **{top}** first "
                  f"({_pct(rows[top]['real_score'])}). The top candidates now sit within half a point of each other, "
                  "inside the inner split's seed noise (results/weighting_check.md), so the rule no longer ships a "
                  "slower graph for a gap that noise explains."]
    lines += ["", f"Chosen: **{rec['chosen']}** (compare row {rec['model']}, `handover train {rec['flags']}`). "
              f"Shipped default (trainer/defaults.py): {rec['shipped']} -- "
              + ("the same." if rec["shipped_matches"] else "**differs from the rule's choice**.")]
    return lines


def mean_real_accuracy(res: dict, name: str) -> float | None:
    """Mean accuracy of a model over the real tasks (None without real tasks)."""
    accs = [r["results"].get(name, {}).get("accuracy") for r in res["real"].values()]
    accs = [a for a in accs if a is not None]
    return float(np.mean(accs)) if accs else None


def plot(res: dict, path: Path) -> Path:
    """Real tasks first: mean real accuracy vs latency, then simulated LOSO (synthetic) vs latency."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("mean accuracy over the real tasks (%)", "Real SDH-2 tasks", lambda n: mean_real_accuracy(res, n)),
              ("leave-one-subject-out accuracy (%)", "Simulated protocol (synthetic data)",
               lambda n: res["simulated"][n]["loso_accuracy"])]
    if not res["real"]:
        panels = panels[1:]
    fig, axes = plt.subplots(1, len(panels), figsize=(6.5 * len(panels), 4.5), squeeze=False)
    for ax, (ylabel, title, score) in zip(axes[0], panels, strict=True):
        points = {m["name"]: (score(m["name"]), res["latency"][m["name"]]["p50_us"]) for m in res["models"]
                  if score(m["name"]) is not None}
        front = set(pareto_front({n: p for n, p in points.items()
                                  if next(m for m in res["models"] if m["name"] == n)["kind"] in ONNX_KINDS}))
        for m in res["models"]:
            n = m["name"]
            if n not in points:
                continue
            acc, lat = 100 * points[n][0], points[n][1]
            onnx = m["kind"] in ONNX_KINDS
            ax.scatter(lat, acc, marker="o" if onnx else "s", s=60, zorder=3,
                       color="C3" if n == "default" else "C1" if n in front else ("C0" if onnx else "C7"))
            ax.annotate(n + ("" if onnx else " (no ONNX)"), (lat, acc), textcoords="offset points", xytext=(5, 4),
                        fontsize=8)
        ax.set_xscale("log")
        ax.set_xlabel("single-case latency, median (us, log scale)")
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
