"""The early decisions in ``handover train``'s report: the accuracy-against-frames curve, per class,
with the rule's operating point marked (figures from ``trainer.early.evaluate``)."""

from __future__ import annotations

from pathlib import Path

from trainer.early import rule_in_words

__all__ = ["console_line", "markdown_lines", "plot_curve", "who_comes_early"]


def markdown_lines(ev: dict, synthetic: bool) -> list[str]:
    """The report.md section of ``metrics["early"]``."""
    if ev.get("skipped"):
        return ["## Early decisions", "", f"Not fitted: {ev['skipped']}.", ""]
    tag = " (**synthetic**)" if synthetic else ""
    points = ev["points"]
    op = ev["operating_point"]
    rule = ev["rule"]
    early = f" ({who_comes_early(rule)})"
    lines = ["## Early decisions", "",
             f"Heads of the default kind at {', '.join(map(str, points[:-1]))} frames after the window's start, the "
             f"full model at {points[-1]}. The rule in the model file: report when the calibrated confidence reaches "
             f"{rule['threshold']:g}{' and the head agrees with the previous one' if rule['agree'] else ''}{early} (chosen as "
             f"{rule_in_words(ev['target_loss'])}). Nested leave-one-subject-out{tag}: each outer fold's rule was chosen inside its "
             "training part, never on the held-out subject.", "",
             "| class | " + " | ".join(f"{p} frames" for p in points) + " | rule: accuracy | rule: mean frames |",
             "|---|" + "---:|" * (len(points) + 2)]
    rows = [("all", ev["curve"], op)] + [(c, ev["curve_per_class"][c], op["per_class"][c]) for c in ev["classes"]]
    for name, curve, at in rows:
        lines.append(f"| {name} | " + " | ".join(f"{curve[str(p)]:.1%}" for p in points)
                     + f" | {at['accuracy']:.1%} | {at['mean_frames']:.1f} |")
    lines += ["", f"Reported at each point: {', '.join(f'{p}: {n}' for p, n in op['reported_at'].items())} "
                  f"(median {op['median_frames']:.0f} frames).", ""]
    return lines


def who_comes_early(rule: dict) -> str:
    """Which classes a rule (``EarlySpec.to_meta``) reports early."""
    classes = rule.get("classes")
    return "every class early" if classes is None else f"{', '.join(classes) or 'no class'} early, the others wait for T"


def console_line(ev: dict | None) -> str | None:
    """The early rule and where the nested evaluation reported, in one line for train's console."""
    if not ev or ev.get("skipped"):
        return None if not ev else f"early decisions: not fitted ({ev['skipped']})"
    rule, op = ev["rule"], ev["operating_point"]
    *early, (T, at_T) = op["reported_at"].items()
    at = ", ".join([*(f"{n} at frame {p}" for p, n in early), f"{at_T} at the full window ({T})"])
    n = sum(op["reported_at"].values())
    return (f"early decisions: report at confidence {rule['threshold']:g} ({who_comes_early(rule)}); in a nested leave "
            f"one subject out over {n} cases (the lab's, and any idle windows of the prior's evidence) the rule "
            f"answered {at}: accuracy {op['accuracy']:.1%}, against {ev['full_accuracy']:.1%} all at the full window")


def plot_curve(ev: dict, path: Path, synthetic: bool) -> Path:
    """Accuracy against frames, per class and overall, the operating point as a star."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = ev["points"]
    fig, ax = plt.subplots(figsize=(6, 4))
    for c in ev["classes"]:
        ax.plot(points, [ev["curve_per_class"][c][str(p)] for p in points], marker="o", lw=1, label=c)
    ax.plot(points, [ev["curve"][str(p)] for p in points], color="k", lw=2, marker="s", label="all")
    op = ev["operating_point"]
    ax.plot([op["mean_frames"]], [op["accuracy"]], marker="*", ms=16, color="crimson", ls="none",
            label=f"rule: {op['accuracy']:.1%} at {op['mean_frames']:.1f} frames")
    ax.set_xlabel("frames after the window's start")
    ax.set_ylabel("accuracy (nested leave-one-subject-out)")
    ax.set_title("Early decisions" + (" (synthetic)" if synthetic else ""))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
