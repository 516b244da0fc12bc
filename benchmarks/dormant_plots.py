"""Figures of ``./dev bench dormant``: a stream timeline with each mode's decisions, the trade-off
between false events and delay, false events by idle source. All data synthetic, titled so."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from firmware_io.sim.constants import FRAME_PERIOD_S
from runtime.trigger_settings import PAPER_FRACTION

__all__ = ["false_by_source", "rule_grid", "timeline", "tradeoff"]

MODE_COLORS = {"threshold": "tab:red", "baseline": "tab:orange", "continuous_plain": "tab:gray",
               "continuous": "tab:blue"}
SOURCE_COLORS = {"arm_move": "#c6dbef", "regrasp": "#fdd0a2", "grasp": "#d9d9d9", "release": "#d9d9d9"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path: Path) -> str:
    """Every figure here at one size and resolution; the file name, for the results page's link."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def _window(truths, n_frames: int, period: float, span_s: float = 75.0) -> tuple[int, int]:
    """A stretch that starts just before an event and holds several of them."""
    n = int(span_s / period)
    start = max(0, truths[min(2, len(truths) - 1)].onset - int(8 / period)) if truths else 0
    return start, min(n_frames, start + n)


def timeline(path: Path, rec, truths, decisions: dict, pads: Sequence[int]) -> str:
    plt = _plt()
    period = float(rec.meta.get("frame_period_s", FRAME_PERIOD_S))
    a, b = _window(truths, rec.n_frames, period)
    cols = rec.layout.columns(list(pads))
    level = rec.frames[a:b, cols].max(axis=1)
    t = (np.arange(a, b) - a) * period
    names = list(rec.meta.get("sources", ()))
    codes = np.asarray(rec.meta.get("source_codes", [0] * rec.n_frames))[a:b]
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(13, 5.5), sharex=True, gridspec_kw={"height_ratios": [2.2, 1]})
    for src, color in SOURCE_COLORS.items():
        if src in names:
            on = codes == names.index(src)
            ax.fill_between(t, 0, 1, where=on, color=color, transform=ax.get_xaxis_transform(), step="mid",
                            label=f"idle: {src}" if on.any() else None)
    ax.plot(t, level, color="k", lw=0.8, label="max taxel of the model's pads")
    fullscale = max(rec.layout.matrices[p].fullscale for p in pads)
    ax.axhline(PAPER_FRACTION * fullscale, color="tab:red", ls=":", lw=1, label=f"{100 * PAPER_FRACTION:.0f} % threshold")
    for tr in truths:
        if a <= tr.onset < b:
            x = (tr.onset - a) * period
            for axis in (ax, ax2):
                axis.axvline(x, color="tab:green", lw=1.2, alpha=0.8)
            ax.text(x, ax.get_ylim()[1] * 0.97, f" {tr.action}", color="tab:green", va="top", fontsize=9)
    ax.set_ylabel("counts")
    ax.legend(loc="upper right", fontsize=7, ncol=3)
    ax.set_title("Mixed stream: truth (green) and each mode's reported events (synthetic, unseen subjects)")
    owned = {}
    for i, tr in enumerate(truths):
        for k in range(max(0, tr.onset - 2), tr.end + 1):
            owned[k] = i
    for row, decs in enumerate(decisions.values()):
        seen: set[int] = set()
        for d in decs:
            if not a <= d.frame < b:
                continue
            i = owned.get(d.frame)
            ok = i is not None and i not in seen and truths[i].action == d.cls
            if i is not None:
                seen.add(i)
            x = (d.frame - a) * period
            ax2.plot(x, row, "o", color="tab:green" if ok else "tab:red", ms=6)
            ax2.text(x, row + 0.22, d.cls, fontsize=7, ha="center")
    ax2.set_yticks(range(len(decisions)), list(decisions))
    ax2.set_ylim(-0.6, len(decisions) - 0.2)
    ax2.set_xlabel("time (s)")
    ax2.set_title("reported events: green = first, right-class report of an event; red = false, wrong or duplicate",
                  fontsize=9)
    return _save(plt, fig, path)


def tradeoff(path: Path, idle: dict, mixed: dict) -> str:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for mode in idle:
        fph = idle[mode]["false_per_hour"] or 0.0
        d = mixed[mode]["delay_s"]
        if d is None:
            continue
        ax.errorbar(max(fph, 0.1), d["median"], yerr=[[d["median"] - d["p10"]], [d["p90"] - d["median"]]], fmt="o",
                    color=MODE_COLORS.get(mode), capsize=4, ms=8,
                    label=f"{mode}: {mixed[mode]['correct']}/{mixed[mode]['n_events']} correct, "
                          f"{mixed[mode]['missed']} missed")
    ax.set_xscale("log")
    ax.set_xlabel("false events per hour of idle stream (log; 0 drawn at 0.1)")
    ax.set_ylabel("detection delay from onset (s), median, p10-p90")
    ax.set_title("False alarms vs delay (synthetic)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save(plt, fig, path)


def false_by_source(path: Path, idle: dict, hours: dict) -> str:
    plt = _plt()
    sources = [s for s in sorted(hours) if hours[s] > 0]
    fig, ax = plt.subplots(figsize=(7.5, 4))
    width = 0.8 / max(1, len(idle))
    x = np.arange(len(sources))
    for k, mode in enumerate(idle):
        rate = [idle[mode]["false_by_source"].get(s, 0) / hours[s] for s in sources]
        ax.bar(x + k * width, rate, width, label=mode, color=MODE_COLORS.get(mode))
    ax.set_xticks(x + width * (len(idle) - 1) / 2, [f"{s}\n{hours[s]:.2f} h" for s in sources], fontsize=8)
    ax.set_ylabel("false events per hour of that situation")
    ax.set_title("False events by what the idle hand was doing (synthetic)")
    ax.legend()
    return _save(plt, fig, path)


def rule_grid(path: Path, rows: list[dict], chosen: dict) -> str:
    """Every report rule tried on the validation streams: false events against correct first reports."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    confirm = np.array([r["confirm_frames"] for r in rows])
    sc = ax.scatter([r["false_events"] + r["duplicates"] for r in rows], [r["correct"] for r in rows], c=confirm,
                    cmap="viridis", s=[12 + 3 * r["rearm_frames"] for r in rows], alpha=0.75)
    best = next(r for r in rows if all(r[k] == v for k, v in chosen.items()))
    ax.scatter([best["false_events"] + best["duplicates"]], [best["correct"]], s=220, facecolors="none",
               edgecolors="tab:red", lw=2, label=f"chosen {chosen}")
    fig.colorbar(sc, ax=ax, label="confirm_frames (marker size: rearm_frames)")
    ax.set_xscale("symlog")
    ax.set_xlabel("false events + duplicates on the validation streams")
    ax.set_ylabel("correct first reports")
    ax.set_title("Continuous report rules on the validation streams (synthetic)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return _save(plt, fig, path)
