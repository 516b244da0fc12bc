"""Figure: synthetic frames against the real SDH-2 recordings (docs/simulator_vs_real.png).

    .venv/bin/./dev bench realism_plot --out docs/simulator_vs_real.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def _intervals(recs) -> np.ndarray:
    d = np.concatenate([np.diff(r.timestamps) for r in recs]) * 1000.0
    return d[d < 100]


def _areas(recs) -> np.ndarray:
    out = []
    for r in recs:
        for pad in range(r.layout.n_matrices):
            v = r.frames[:, r.layout.matrix_slice(pad)]
            on = v.max(axis=1) >= 100
            out.append((v[on] > 0).sum(axis=1))
    return np.concatenate(out)


def make_figure(real, sim, out: Path, seed: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from firmware_io.layout import SensorLayout

    fig, ax = plt.subplots(2, 2, figsize=(9, 6.2), dpi=80)
    bins = np.arange(14.5, 50.5, 1.0)
    for recs, label in ((real, "real"), (sim, "synthetic")):
        ax[0, 0].hist(_intervals(recs), bins=bins, density=True, histtype="step", lw=1.5, label=label)
        nz = np.concatenate([r.frames[r.frames > 0] for r in recs])
        ax[0, 1].hist(nz, bins=np.arange(0, 4200, 100), density=True, histtype="step", lw=1.5, label=label)
        ax[1, 0].hist(_areas(recs), bins=np.arange(0.5, 60.5, 2), density=True, histtype="step", lw=1.5, label=label)
    ax[0, 0].set(title="frame interval (ms)", yscale="log")
    ax[0, 1].set(title="non-zero taxel values (counts)", yscale="log")
    ax[0, 1].axvline(614, color="k", ls=":", lw=1)
    ax[1, 0].set(title="taxels in contact per pad")
    distal = SensorLayout.sdh2().columns("distal")
    rec = sim[0]
    shown = set()
    for tr in rec.trials:
        if tr.action in shown or tr.pose != "down" or tr.object != "ball":
            continue
        shown.add(tr.action)
        f, _ = rec.trial_frames(tr)
        t = (np.arange(len(f)) - tr.extra["onset"]) * 0.0316
        ax[1, 1].plot(t, f[:, distal].max(axis=1), label=tr.action)
    ax[1, 1].axhline(614, color="k", ls=":", lw=1)
    ax[1, 1].set(title="synthetic: max distal taxel (ball, pose down)", xlabel="s from onset")
    for a in ax.ravel():
        a.legend(fontsize=8)
    fig.suptitle(f"simulated hand (synthetic, seed {seed}) vs real SDH-2 recordings (Kiechle 2015)", fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="./dev bench realism_plot", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/simulator_vs_real.png"))
    parser.add_argument("--real", type=Path, default=Path(__file__).resolve().parents[2] / "shared/data/sdh2-dsa")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    from firmware_io.sim import realism, simulate_protocol

    if not args.real.is_dir():
        print(f"realism_plot: real recordings folder {args.real} not found", file=sys.stderr)
        return 1
    real = realism.load_real(args.real)
    sim = simulate_protocol(seed=args.seed, n_subjects=2, runs=2)
    make_figure(real, sim, args.out, args.seed)
    print(f"wrote {args.out}")
    return 0
