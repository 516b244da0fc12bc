"""``handover plot``: a figure of one trial of a recording (per-pad sum over time, taxels at the peak).

Used to look at a trial flagged during recording, or at any trial before training on it. The
trigger drawn is the one a daemon would run on this trial: the model's (``--model``: its recorded
settings and pads, as ``runtime.trigger_settings.resolve_trigger`` takes them), else the
daemon's default, with the window it cuts; the legend sits beside the curves, never over them.
matplotlib is imported inside ``main`` (Agg backend: works on a robot PC without a display).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from firmware_io.commands.options import trigger_level
from firmware_io.errors import HandoverError
from runtime.trigger_settings import PAPER_FRACTION

__all__ = ["add_arguments", "main"]



def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", help="a .hrec recording")
    parser.add_argument("--trial", type=int, default=1, help="trial number, 1-based as listed by --list (default 1)")
    parser.add_argument("--out", help="PNG to write (default: RECORDING-stem_trialN.png in the current folder)")
    parser.add_argument("--list", action="store_true", help="list the trials and exit")
    parser.add_argument("--model", metavar="MODEL.onnx", default=None,
                        help="draw the trigger this model uses (its recorded kind and settings, its pads and window); "
                             "default: the daemon's default trigger on all pads")
    parser.add_argument("--trigger", choices=("onset", "threshold"), default=None,
                        help="another trigger kind than the model's (as [trigger] kind in the daemon's config)")
    parser.add_argument("--fraction", type=trigger_level, default=None,
                        help=f"threshold trigger's level, fraction of full scale (default: the model's, else {PAPER_FRACTION})")


def main(args: argparse.Namespace) -> int:
    from firmware_io.recordings.recording import Recording

    rec = Recording.load(args.recording)
    if args.list:
        from firmware_io.recordings.record_session import flagged_trials

        flagged = set(flagged_trials(rec))
        for i, t in enumerate(rec.trials, start=1):
            flag = f"  flagged: {t.extra.get('no_case') or 'never triggered'}" if i - 1 in flagged else ""
            print(f"{i:4d}  {t.subject} {t.pose} {t.object} {t.action} run {t.run}  ({t.n_frames} frames){flag}")
        return 0
    if not rec.trials:
        raise HandoverError(f"{args.recording}: the recording holds no trials")
    if not 1 <= args.trial <= len(rec.trials):
        raise HandoverError(f"--trial {args.trial}: the recording has trials 1..{len(rec.trials)}")
    out = Path(args.out) if args.out else Path(f"{Path(args.recording).stem}_trial{args.trial}.png")
    try:
        drawn = model_trigger(rec, args.model, args.trigger, args.fraction)
    except ValueError as exc:  # a model or trigger option that cannot draw
        raise HandoverError(str(exc)) from exc
    try:
        path = plot_trial(rec, args.trial - 1, out, trigger=drawn)
    except OSError as exc:
        raise HandoverError(f"{out}: cannot write ({exc.strerror or exc})") from None
    print(path)
    return 0


class DrawnTrigger:
    """The trigger a daemon would run: its settings, the scene's pads and the model's window ``T``."""

    def __init__(self, settings, pads: tuple[int, ...], T: int, rate_hz: float | None, source: str) -> None:
        self.settings, self.pads, self.T, self.rate_hz, self.source = settings, pads, T, rate_hz, source

    @property
    def label(self) -> str:
        s = self.settings
        what = f"{s.fraction:.0%} of full scale" if s.kind == "threshold" else f"change {s.change:.0%}"
        return f"{s.name} trigger ({what}; {self.source})"

    def fires(self, frames, layout, rate_hz: float) -> list[tuple[int, int, int]]:
        """(frame it fires at, window first, window last) for every window it starts in ``frames``."""
        import numpy as np

        from runtime.trigger_settings import build_trigger

        cols = layout.columns(self.pads)
        rate = self.rate_hz or rate_hz
        trig = build_trigger(self.settings, tuple(layout.pad_sizes(self.pads)), layout.fullscale, self.T, rate,
                             tuple(layout.pad_fingers(self.pads)))
        if hasattr(trig, "set_grasp"):
            trig.set_grasp(True)  # a protocol trial starts on the held object (as the training windows are cut)
        rows = frames[:, cols].astype(np.float32)
        out = []
        for i in range(len(rows)):
            due = trig.update(rows[i], i)
            if due >= 0:
                out.append((i, due - self.T + 1, due))
        return out


def model_trigger(rec, model_path: str | None, kind: str | None = None, fraction: float | None = None) -> DrawnTrigger:
    """The trigger ``model_path`` would be served with (config overrides ``kind``/``fraction`` as in
    ``[trigger]``); without a model the daemon's default on all pads. ValueError: one line."""
    from runtime.config import TriggerConfig
    from runtime.trigger_settings import resolve_trigger

    config = TriggerConfig(kind=kind, fraction=fraction)
    pads = tuple(range(rec.layout.n_matrices))
    if model_path is None:
        return DrawnTrigger(resolve_trigger(config, None), pads, DEFAULT_T, None, "default, no model")
    from runtime.model import ModelContractError, load_model

    try:
        model = load_model(model_path, warm_up=False)
    except ModelContractError as exc:
        raise ValueError(str(exc)) from None
    meta = model.meta
    bad = [p for p in meta.pads if p >= rec.layout.n_matrices]
    if bad:
        raise ValueError(f"--model {model_path}: its pads {list(meta.pads)} are not all in this recording "
                         f"(matrices 0-{rec.layout.n_matrices - 1})")
    return DrawnTrigger(resolve_trigger(config, meta.trigger), tuple(meta.pads), int(meta.T),
                        float(meta.sample_rate_hz), f"model {Path(model_path).name}")


DEFAULT_T = 16
"""Window drawn without a model (the default models' T)."""


def plot_trial(rec, index: int, out: Path, trigger: DrawnTrigger | None = None) -> Path:
    """Write ``trial_figure`` as a PNG."""
    import matplotlib.pyplot as plt

    fig = trial_figure(rec, index, trigger)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return out


def trial_figure(rec, index: int, trigger: DrawnTrigger | None = None):
    """Top: each pad's summed pressure over time, with where the trigger fires and the window it
    cuts. Bottom: every pad's taxels at the peak frame."""
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
    trigger = trigger or model_trigger(rec, None)
    rate = 1.0 / rec.period_s()
    for k, (at, first, last) in enumerate(trigger.fires(frames, layout, rate)):
        ax.axvline(t[at], color="red", linestyle="--", label=trigger.label if k == 0 else None)
        lo, hi = t[max(first, 0)], t[min(last, len(t) - 1)]
        ax.axvspan(lo, hi, color="red", alpha=0.08, label="window the model reads" if k == 0 else None)
    ax.set_xlabel("time in trial (s)")
    ax.set_ylabel("sum of taxel values")
    synthetic = " (synthetic data)" if rec.meta.get("synthetic") or trial.extra.get("synthetic") else ""
    ax.set_title(f"trial {index + 1}: {trial.subject}, {trial.pose}, {trial.object}, {trial.action}, "
                 f"run {trial.run}{synthetic}")
    # beside the curves, not over them
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
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
    return fig
