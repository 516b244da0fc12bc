"""Per-frame compute while a window is open, with early heads: the cost of deciding before T.

A model with early heads runs one head at each of its points after the trigger until the rule
reports, then nothing more for that event; without heads a frame inside a window only pushes the
ring and tests the trigger. Measured here: every ``Detector.feed`` call (the daemon's hot path,
runtime/detector.py) of a simulated session
(scripted handovers by unseen simulated subjects, the onset trigger) timed in this process, split into
frames inside an open window (from the trigger to the report) and the others; the default model
with early heads (trained on the simulated protocol, synthetic) against the same model without,
at the daemon's real-time priority like the stage tables.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from trainer.measure import percentiles


def early_model(work: Path, seed: int, quick: bool) -> tuple[Path, Path]:
    """The default model on onset-cut windows, exported with and without early heads."""
    from trainer import early
    from trainer.dataset import build_dataset
    from trainer.measure import export_metadata, simulated_protocol
    from trainer.onnx_export import export_onnx

    ds = build_dataset(list(simulated_protocol(seed, quick)), T=15, pads="all")
    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    make = early.head_factory(ds.pad_sizes, shapes, seed, ds.fullscale)
    heads = early.fit_early(ds.X, ds.y, ds.groups, make, make)
    full = make(15).fit(ds.X, ds.y)
    meta = export_metadata(ds, full, seed=seed)
    return (export_onnx(full, work / "early.onnx", meta, early=heads), export_onnx(full, work / "plain.onnx", meta))


def timed_replay(model, rec) -> dict:
    """``Detector.feed`` (the daemon's hot path) of every frame of ``rec`` timed; inside-window frames apart."""
    from firmware_io.client import Frame
    from runtime.config import config_from_dict
    from runtime.detector import Detector

    cfg = config_from_dict({"scene": {"pads": ",".join(map(str, model.meta.pads)), "mode": "trigger"},
                            "trigger": {"kind": "onset"}})
    detector = Detector.from_config(cfg)
    detector.swap(model, rec.layout)
    stamps = np.rint(rec.timestamps * 1000.0).astype(np.int64)
    inside, outside, events = [], [], 0
    clock = time.perf_counter
    for i in range(rec.n_frames):
        frame = Frame(i, int(stamps[i]), clock(), rec.frames[i])
        was_open = detector.window_open
        t0 = clock()
        decision = detector.feed(frame)
        took = (clock() - t0) * 1e6
        events += decision is not None and decision.cls is not None
        (inside if was_open or detector.window_open else outside).append(took)
    return {"inside_window": percentiles(inside), "outside_window": percentiles(outside), "events": int(events)}


def early_frames(paths: tuple[Path, Path], seed: int, quick: bool, say) -> dict:
    """The table's figures: per-frame compute inside a window with and without early heads
    (``paths``: ``early_model``'s two files)."""
    from firmware_io.sim import demo_script, simulate_session
    from runtime.model import load_model

    say("latency: per-frame compute inside a window, with and without early heads (synthetic) ...")
    with_heads, without = paths
    n = 8 if quick else 40
    session = simulate_session(demo_script(n, seed=seed + 7), seed=seed + 7)
    out, points = {}, None
    for name, path in (("early", with_heads), ("full_window_only", without)):
        model = load_model(path, intra_op_threads=1, allow_spinning=False)
        timed_replay(model, session)  # warm: first calls pay for allocations
        out[name] = timed_replay(model, session)
        points = points or list(model.early.points)
    out["points"] = points
    out["session_events"] = n
    return out


def markdown_lines(res: dict | None) -> list[str]:
    if not res:
        return []
    lines = ["## Per-frame compute inside a window (early heads)", "",
             "Every `Detector.feed` call (the daemon's hot path) of a simulated session (synthetic, "
             f"{res['session_events']} scripted handovers, onset trigger) timed in this process, frames inside an "
             f"open window (trigger to report) apart. `early`: the default model with heads at "
             f"{', '.join(map(str, res['points']))} frames (one head runs at each point until the rule reports); "
             "`full_window_only`: the same model without heads.", "",
             "| model | frames | median (us) | p99 (us) | max (us) | n | events |", "|---|---|---:|---:|---:|---:|---:|"]
    for name in ("early", "full_window_only"):
        r = res[name]
        for part in ("inside_window", "outside_window"):
            s = r[part]
            if s["n"]:
                lines.append(f"| {name} | {part.replace('_', ' ')} | {s['p50']:.0f} | {s['p99']:.0f} | {s['max']:.0f} | "
                             f"{s['n']} | {r['events']} |")
    return [*lines, ""]
