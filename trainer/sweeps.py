"""The paper's one-at-a-time sweeps of K, W and T (and the kernel), shared by train and sweep.

Each sweep varies one parameter and keeps the others at the chosen setting, as in the paper's
figures. Points whose window does not fit (T - 1 < W) are left out and listed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from firmware_io.recordings.recording import Recording
from trainer.classifier import BowSVC
from trainer.dataset import build_dataset
from trainer.defaults import paper_classifier
from trainer.evaluation import sweep

__all__ = ["FULL_K", "FULL_T", "FULL_W", "QUICK_K", "QUICK_T", "QUICK_W", "run_sweeps"]

QUICK_K = (4, 7, 10, 15, 20)
QUICK_W = (3, 5, 7, 9)
QUICK_T = (10, 15, 20)
FULL_K = (2, 4, 6, 8, 10, 12, 15, 20, 30)
FULL_W = (2, 3, 4, 5, 6, 7, 8, 9, 10, 12)
FULL_T = (8, 10, 12, 15, 18, 20, 25, 30)


def make_bow(params: dict) -> BowSVC:
    """Module-level (picklable for joblib workers)."""
    return paper_classifier(params.get("pad_sizes"), params.get("seed", 0), n_words=params["K"], window=params["W"],
                            kernel=params["kernel"], per_pad=params.get("per_pad", False))


def run_sweeps(
    recordings: Sequence[Recording],
    base: dict,
    K_values: Sequence[int],
    W_values: Sequence[int],
    T_values: Sequence[int],
    kernels: Sequence[str],
    pads: str,
    fraction: float,
    mode: str = "config1",
    seeds: Sequence[int] = (0,),
    progress: Callable | None = None,
) -> dict:
    """Run all one-at-a-time sweeps; ``base`` has K, W, T, seed, per_pad. Returns description + rows."""
    data = {}

    def data_for(T: int):
        if T not in data:
            ds = build_dataset(recordings, T=T, pads=pads, fraction=fraction)
            data[T] = (ds.X, ds.y, ds.groups)
            data[(T, "sizes")] = ds.pad_sizes
        return data[T]

    points, labels, skipped = [], [], []
    for kernel in kernels:
        for param, values in (("K", K_values), ("W", W_values), ("T", T_values)):
            for v in values:
                p = {"K": base["K"], "W": base["W"], "T": base["T"], "kernel": kernel, "seed": base.get("seed", 0),
                     "per_pad": base.get("per_pad", False)}
                p[param] = int(v)
                if p["T"] - 1 < p["W"]:
                    skipped.append(f"{param}={v} (W={p['W']} needs T >= {p['W'] + 1})")
                    continue
                X, y, groups = data_for(p["T"])
                if p["per_pad"]:
                    p["pad_sizes"] = tuple(data[(p["T"], "sizes")])
                points.append((p, (X, y, groups)))
                labels.append(param)
    results = sweep(make_bow, points, mode=mode, seeds=seeds, progress=progress)
    rows = []
    for param, r in zip(labels, results, strict=True):
        r = {k: v for k, v in r.items() if k != "pad_sizes"}
        rows.append({"param": param, **r})
    what = ("leave-one-subject-out accuracy (all held-out predictions), std over subjects" if mode == "loso"
            else f"configuration 1 accuracy (stratified random 80/20), mean +/- std over seeds {list(seeds)}")
    description = (f"One parameter at a time around K={base['K']}, W={base['W']}, T={base['T']}; {what}; "
                   f"C/gamma searched inside each fit.")
    if skipped:
        description += " Left out: " + ", ".join(skipped) + "."
    return {"description": description, "mode": mode, "seeds": list(seeds), "rows": rows}
