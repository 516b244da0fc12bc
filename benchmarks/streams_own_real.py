"""A lab's own model trained with REAL idle, measured on real idle it never saw (part of ``./dev bench streams_own``).

Why: every other own-model idle figure rests on synthetic idle, and a robot's idle is real signals. Half of the
real SDH-2 recordings without a handover (../shared/data; the streams bench's validation half, every other file)
become the lab's idle (``handover import --idle quiet --subject S``, spread over the scripted subjects so that
leave-one-subject-out holds each file out with a subject); ``handover train`` trains on them with the subjects'
trials and measures its held-out replay on them (the figure the model file carries, runtime/model_meta.py
``real_false_events``); the model is then replayed on the other half (the streams bench's test half), split by
file, in onset_dormant and in continuous mode.
"""

from __future__ import annotations

import contextlib
import io
import shutil
from pathlib import Path

IDLE_KIND = "quiet"
"""What the imported files are marked as: one label for all (they hold grasps, weights put on the pads and slips;
nobody hands anything over)."""


SKIPPED = "fast"
"""A category not used as the lab's idle: recorded at ~70 Hz for frequency analysis, not a robot's stream rate."""


def halves(root: Path) -> tuple[list[Path], list[Path]]:
    """(the lab's idle, held out): the streams bench's split by file (benchmarks/streams.py ``evaluate_real``),
    the lab's half without ``SKIPPED`` files."""
    from trainer.shared_data import real_files

    files = real_files(root)
    lab = [path for path, cat, _ in files[0::2] if cat != SKIPPED]
    return lab, [path for path, _, _ in files[1::2]]


def import_idle(files: list[Path], data: Path, subjects: list[str]) -> dict[str, int]:
    """``handover import`` of ``files`` as idle into ``data``, spread over ``subjects``; exit code per subject."""
    from runtime.cli import main as handover

    codes = {}
    for k, subject in enumerate(subjects):
        mine = [str(f) for f in files[k::len(subjects)]]
        if mine:
            with contextlib.redirect_stdout(io.StringIO()):
                codes[subject] = handover(["import", *mine, "--out", str(data), "--idle", IDLE_KIND,
                                           "--subject", subject])
    return codes


def run_real(subjects_data: Path, work: Path, subjects: list[str], seed: int, quick: bool, say) -> dict | None:
    """Train with half the real recordings as idle, replay the other half; None without ../shared/data."""
    from runtime.model import load_model
    from runtime.model_meta import real_false_events
    from trainer.own_replay import real_idle
    from trainer.pipeline import train
    from trainer.shared_data import default_data_dir
    from trainer.train_options import TrainOptions

    root = default_data_dir()
    if not root.is_dir():
        return None
    lab, held = halves(root)
    if quick:
        lab, held = lab[::10], held[::10]
    data = work / "data_real"
    data.mkdir()
    for f in sorted(subjects_data.glob("*.hrec")):
        shutil.copy(f, data / f.name)
    say(f"streams_own: importing {len(lab)} real recordings as the lab's idle ({IDLE_KIND}) ...")
    codes = import_idle(lab, data, subjects)
    say("streams_own: handover train with the real idle ...")
    result = train(TrainOptions(data=str(data), out=str(work / "report_real"), no_sweep=True, repeats=2, quiet=True,
                                seed=seed, real_idle=False))
    model = load_model(work / "report_real" / "model.onnx", warm_up=False)
    say(f"streams_own: replaying the {len(held)} held-out real recordings (onset_dormant, continuous) ...")
    held_out = {mode: real_idle(model, root, say, files=held, mode=mode) for mode in ("onset_dormant", "continuous")}
    m = result.metrics
    return {
        "lab_idle_files": [str(f.relative_to(root)) for f in lab], "import_exit_codes": codes,
        "held_out_files": len(held), "idle_kind": IDLE_KIND,
        "model": {"classes": list(model.meta.classes), "n_trials": m["n_trials"], "idle": m.get("idle"),
                  "data_notes": m.get("data_notes")},
        "carried": real_false_events(model.meta),
        "held_out_replay": m.get("own_replay"),
        "held_out_names": [str(f.relative_to(root)) for f in held],
        "held_out": {mode: r for mode, r in held_out.items() if r},
    }


def on_half(real: dict | None, lab: dict | None) -> dict | None:
    """The synthetic-idle model's figure (``real``: its ``real_idle`` rows of every file) on ``lab``'s held-out half."""
    if not real or not lab:
        return None
    names = set(lab["held_out_names"])
    rows = [r for r in real["rows"] if r["file"] in names and "events" in r]
    hours = sum(r["hours"] for r in rows)
    events = sum(len(r["events"]) for r in rows)
    return {"files": len(rows), "hours": hours, "events": events, "false_per_hour": events / hours if hours else None}


def rate(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def markdown(r: dict | None, synthetic_half: dict | None, demo_half: float | None) -> list[str]:
    """The section of results/streams_own.md."""
    lines = ["## Trained with real idle (half the real recordings), measured on the other half", ""]
    if not r:
        return [*lines, "Not measured: the real recordings (../shared/data) are not on this machine.", ""]
    od, cont = r["held_out"].get("onset_dormant"), r["held_out"].get("continuous")
    carried = "; ".join(f"{k} {v['per_hour']:.2f} per hour ({v['events']} in {v['hours']:.2f} h)"
                        for k, v in r["carried"].items()) or "nothing (unmeasured)"
    idle = r["model"].get("idle") or {}
    lines += [
        f"The three subjects' recordings plus {len(r['lab_idle_files'])} real recordings imported as idle "
        f"(`handover import --idle {r['idle_kind']} --subject sN`, every other file of ../shared/data: the streams "
        f"bench's validation half); `handover train`: {idle.get('dormant_windows', '-')} dormant windows from "
        f"{(idle.get('seconds') or 0) / 3600:.2f} h of idle. Real signals, synthetic trials.",
        "",
        "| measured on | setting | hours | false events | per hour |",
        "|---|---|---|---|---|",
    ]
    rep = (r.get("held_out_replay") or {}).get("real_idle") or {}
    for name, v in (rep.get("settings") or {}).items():
        lines.append(f"| `handover train`'s held-out replay of the real idle (each file through a model trained "
                     f"without its subject; what the model file carries) | {name} | {v['hours']:.2f} | "
                     f"{v['events']} | {rate(v['per_hour'])} |")
    for name, x in (("onset_dormant", od), ("continuous", cont)):
        if x:
            lines.append(f"| the other half ({r['held_out_files']} files, never trained on) | {name} | "
                         f"{x['hours']:.2f} | {x['events']} | **{rate(x['false_per_hour'])}** |")
    if synthetic_half:
        lines.append(f"| the other half: the own model trained with synthetic idle (above) | onset_dormant | "
                     f"{synthetic_half['hours']:.2f} | {synthetic_half['events']} | "
                     f"{rate(synthetic_half['false_per_hour'])} |")
    if demo_half is not None:
        lines.append(f"| the other half: the demo's simulator-trained model (results/streams.json "
                     f"`real_test_half_false_events_per_hour`) | onset_dormant | - | - | {rate(demo_half)} |")
    lines += ["", f"The model file carries (`handover inspect`): {carried}.",
              *(f"- train said: {n}" for n in r["model"].get("data_notes") or []), ""]
    return lines
