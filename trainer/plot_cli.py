"""``handover plot``: a figure of one trial of a recording (per-pad sum over time, taxels at the peak).

Used to look at a trial flagged during recording, or at any trial before training on it.
matplotlib is imported inside ``main`` (Agg backend: works on a robot PC without a display).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from firmware_io.commands.errors import fail
from runtime.trigger_settings import PAPER_FRACTION

COMMAND = "plot"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", help="a .hrec recording")
    parser.add_argument("--trial", type=int, default=1, help="trial number, 1-based as listed by --list (default 1)")
    parser.add_argument("--out", help="PNG to write (default: RECORDING-stem_trialN.png in the current folder)")
    parser.add_argument("--list", action="store_true", help="list the trials and exit")
    parser.add_argument("--fraction", type=float, default=PAPER_FRACTION,
                        help=f"trigger level drawn, fraction of full scale (default: the paper's {PAPER_FRACTION})")


def main(args: argparse.Namespace) -> int:
    from firmware_io.recordings.recording import Recording, RecordingError

    try:
        rec = Recording.load(args.recording)
    except RecordingError as exc:
        return fail(COMMAND, str(exc))
    if args.list:
        for i, t in enumerate(rec.trials, start=1):
            flag = "  never triggered" if t.extra.get("triggered") is False else ""
            print(f"{i:4d}  {t.subject} {t.pose} {t.object} {t.action} run {t.run}  ({t.n_frames} frames){flag}")
        return 0
    if not rec.trials:
        return fail(COMMAND, f"{args.recording}: the recording holds no trials")
    if not 1 <= args.trial <= len(rec.trials):
        return fail(COMMAND, f"--trial {args.trial}: the recording has trials 1..{len(rec.trials)}")
    out = Path(args.out) if args.out else Path(f"{Path(args.recording).stem}_trial{args.trial}.png")
    try:
        path = plot_trial(rec, args.trial - 1, out, fraction=args.fraction)
    except OSError as exc:
        return fail(COMMAND, f"{out}: cannot write ({exc.strerror or exc})")
    print(path)
    return 0


def plot_trial(rec, index: int, out: Path, fraction: float = PAPER_FRACTION) -> Path:
    """Top: each pad's summed pressure over time. Bottom: every pad's taxels at the peak frame."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from firmware_io.recordings.terminal_view import pad_name, pad_sums

    layout = rec.layout
    trial = rec.trials[index]
    frames, stamps = rec.trial_frames(trial)
    t = stamps - stamps[0]
    sums = pad_sums(frames, layout)
    peak = int(np.argmax(frames.max(axis=1))) if len(frames) else 0
    n_pads = layout.n_matrices
    fig = plt.figure(figsize=(max(8.0, 1.6 * n_pads), 7.5))
    grid = fig.add_gridspec(2, n_pads, height_ratios=(1.2, 1.0))
    ax = fig.add_subplot(grid[0, :])
    for i in range(n_pads):
        ax.plot(t, sums[:, i], label=pad_name(layout, i))
    ax.axvline(t[peak], color="0.5", linestyle=":", label="peak frame")
    trig = trial.extra.get("trigger_frame", -1)
    if isinstance(trig, int) and 0 <= trig < len(t):
        ax.axvline(t[trig], color="red", linestyle="--", label=f"trigger ({fraction:.0%} full scale)")
    ax.set_xlabel("time in trial (s)")
    ax.set_ylabel("sum of taxel values")
    synthetic = " (synthetic data)" if rec.meta.get("synthetic") or trial.extra.get("synthetic") else ""
    ax.set_title(f"trial {index + 1}: {trial.subject}, {trial.pose}, {trial.object}, {trial.action}, "
                 f"run {trial.run}{synthetic}")
    ax.legend(fontsize=8, ncol=min(4, n_pads + 2))
    vmax = layout.fullscale
    for i in range(n_pads):
        m = layout.matrices[i]
        img = frames[peak, layout.matrix_slice(i)].reshape(m.cells_y, m.cells_x).astype(float)
        img[~m.mask] = np.nan
        sub = fig.add_subplot(grid[1, i])
        shown = sub.imshow(img, vmin=0, vmax=vmax, cmap="viridis", interpolation="nearest")
        sub.set_title(pad_name(layout, i), fontsize=9)
        sub.set_xticks([])
        sub.set_yticks([])
    fig.colorbar(shown, ax=fig.axes[1:], shrink=0.8, label=f"taxel value at t = {t[peak]:.2f} s")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
