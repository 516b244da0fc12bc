"""results/latency.md and latency.png from the latency benchmark's result (``trainer.bench.latency``):
the headline figures against their targets, each stage's table, the limits of this machine."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from runtime.detector import REHEARSAL_LEAD_S
from runtime.realtime import DEFAULT_PRIORITY
from trainer.bench import latency_stages as stages
from trainer.bench.latency_early import markdown_lines as early_lines
from trainer.bench.latency_shadow import TARGET_RATIO
from trainer.bench.latency_shadow import markdown_lines as shadow_lines
from trainer.measure import DEADLINE_US, deadline_ratio, fmt_us

TARGETS = {"onnx_p50_us": 30.0, "onnx_p50_us_all_pads": 60.0, "daemon_p999_us": 200.0, "e2e_p999_us": 500.0,
           "e2e_p999_us_load": 1000.0, "paced_over_back_to_back": 1.5, "shadow_p999_ratio": TARGET_RATIO,
           "shadow_capture_p999_ratio": TARGET_RATIO, "rss_mb": 80.0}
"""The latency targets (at most), each key as written to latency.json."""


def headline(res: dict) -> dict:
    """The issue's keys (None where the run did not measure it)."""
    quiet = res["stages"]
    continuous = quiet.get("continuous_paced_32hz", {}).get("daemon_internal", {})
    internal_fast, internal_paced = (quiet[k]["daemon_internal"] for k in ("back_to_back", "paced_32hz"))
    e2e = res["e2e_32hz"]["e2e_us"]
    load = res.get("e2e_32hz_load")
    return {
        # the graph alone, warm (``solo``); the interleaved table is for the ratios below
        "onnx_p50_us": res["implementations_distal"]["solo"]["onnxruntime"]["p50"],
        "onnx_p50_us_all_pads": res["implementations"]["solo"]["onnxruntime"]["p50"],
        "onnx_p99_us": res["implementations"]["solo"]["onnxruntime"]["p99"],
        "daemon_p999_us": internal_paced["p999"],
        "daemon_p50_us": internal_paced["p50"],
        # continuous mode (every frame a decision): not a target
        "continuous_daemon_p50_us": continuous.get("p50"),
        "continuous_daemon_p999_us": continuous.get("p999"),
        "paced_over_back_to_back": internal_paced["p50"] / internal_fast["p50"],
        "e2e_p50_us": e2e["p50"], "e2e_p99_us": e2e["p99"], "e2e_p999_us": e2e["p999"], "e2e_max_us": e2e["max"],
        "e2e_p999_us_load": load["e2e_us"]["p999"] if load else None,
        "e2e_load_p99_us": load["e2e_us"]["p99"] if load else None,
        "rss_mb": res["e2e_32hz"]["rss_mb"],
        # the same windows, interleaved: these ratios hold on a noisy machine (None: not measured)
        # the limits: a steady job as long as the paced median, on this machine; the per-frame split
        "floor_p999_us": _floor(res, "paced"),
        "e2e_floor_p999_us": _floor(res, "e2e"),
        "split_p50_us": (res["implementations_distal"].get("per_frame_split") or {}).get("decision_with_its_frame_p50_us"),
        # early heads: every frame from the trigger to the report (trainer/bench/latency_early.py)
        "early_inside_window_p99_us": ((res.get("early_frames") or {}).get("early") or {}).get(
            "inside_window", {}).get("p99"),
        # the serving decision's p99.9 with a candidate in shadow over that without (trainer/bench/latency_shadow.py)
        "shadow_p999_ratio": (res.get("shadow") or {}).get("p999_ratio", {}).get("shadow"),
        "shadow_capture_p999_ratio": (res.get("shadow") or {}).get("p999_ratio", {}).get("shadow + capture"),
    }


def job_lengths(res: dict) -> dict[str, float | None]:
    """The medians whose floor the results give: frame parsed -> decision back to back and paced, and
    end to end."""
    stages = res["stages"]
    return {"back_to_back": stages["back_to_back"]["daemon_internal"]["p50"],
            "paced": stages["paced_32hz"]["daemon_internal"]["p50"], "e2e": res["e2e_32hz"]["e2e_us"]["p50"]}


def _floor(res: dict, name: str) -> float | None:
    """p99.9 of a steady job as long as the ``name`` median (``job_lengths``) on this machine."""
    job = res.get("interference", {}).get("steady_job_us", {}).get(name)
    return job["p999"] if job else None


def _limit_lines(res: dict) -> list[str]:
    """The machine's interference and the per-frame split, as measured in this run."""
    lines = ["## What the machine and the method allow", ""]
    inter = res.get("interference")
    if inter:
        gap = inter["gap_us"]
        lines += [f"A thread that only reads the clock (same scheduling as the stage tables, {inter['spun_s']:g} s "
                  f"of spinning) lost its core {inter['gaps_per_s']:.0f} times a second: median {fmt_us(gap['p50'])} us, "
                  f"p99 {fmt_us(gap['p99'])} us, longest {fmt_us(gap['max'])} us. A job that always needs the same "
                  "time of the core, started at random moments, therefore takes:", "",
                  "| steady job (us of core) | median (us) | p99 (us) | p99.9 (us) |", "|---|---|---|---|"]
        for s in inter["steady_job_us"].values():
            lines.append(f"| {s['job_us']} | {fmt_us(s['p50'])} | {fmt_us(s['p99'])} | {fmt_us(s['p999'])} |")
        lines += ["", "The job lengths are this run's medians of frame parsed -> decision, back to back and paced, "
                  "and of end to end. `floor_p999_us` is the paced one's p99.9: the lowest `daemon_p999_us` this "
                  "machine allows at that median, even if every decision needed exactly the median; "
                  "`e2e_floor_p999_us` the same for `e2e_p999_us` (three processes, so the true floor is higher).",
                  ""]
    rows = [(pads, res[key].get("per_frame_split")) for key, pads in
            (("implementations", "all pads"), ("implementations_distal", "distal pads"))]
    if any(split for _, split in rows):
        lines += ["The per-frame split of the default graph (`trainer/bench/latency_floor.py`): cut at the per-pad "
                  "series, whose rows depend on one frame each; the part before the cut runs as each frame arrives, "
                  "the part after it (the window's statistics and the SVM, reading the series and the window) on the "
                  "decision. The decision's own frame still needs the first part. Each alone, back to back:", "",
                  "| pads | whole graph (us, nodes) | per-frame part, one frame (us, nodes) | decision part (us, nodes) "
                  "| decision with its frame (us) | scores, split against whole |", "|---|---|---|---|---|---|"]
        for pads, split in rows:
            if split:
                n = split["nodes"]
                lines.append(f"| {pads} | {fmt_us(split['whole']['p50'])}, {n['whole']} | "
                             f"{fmt_us(split['per_frame_part']['p50'])}, {n['per_frame_part']} | "
                             f"{fmt_us(split['decision_part']['p50'])}, {n['decision_part']} | "
                             f"{fmt_us(split['decision_with_its_frame_p50_us'])} | "
                             f"within {split['max_score_difference']:.1e} |")
        lines += ["", "`split_p50_us` is the distal row's decision with its frame. onnxruntime costs a few tenths of a "
                  "microsecond per node and a few microseconds per run whatever the tensors' size, and the window is "
                  "only 15 frames: what the split saves in arithmetic, the second run and the per-frame part's nodes "
                  "on the decision's frame cost again.", ""]
    return lines


def _row(name: str, s: dict) -> str:
    r = deadline_ratio(s)
    ratio = " / ".join("-" if r[k] is None else f"{r[k]:,.0f}x" for k in ("p50", "p99", "p999", "max"))
    return (f"| {name} | {fmt_us(s['p50'])} | {fmt_us(s['p99'])} | {fmt_us(s['p999'])} | {fmt_us(s['max'])} | "
            f"{s['n']} | {ratio} |")


HEAD = ["| what | median (us) | p99 (us) | p99.9 (us) | max (us) | n | deadline / figure (p50 / p99 / p99.9 / max) |",
        "|---|---|---|---|---|---|---|"]
RHYTHM_TITLES = {"back_to_back": "back to back", "paced_32hz": "paced at 32 Hz",
                 "paced_32hz_not_rehearsed": "paced at 32 Hz, not rehearsed (for comparison)",
                 "continuous_paced_32hz": "continuous mode, paced at 32 Hz"}
"""Stage tables' headings."""

STAGE_TITLES = {
    "receive": "frame bytes -> Frame: parse + CRC + decode + plausibility (DSAClient.read_frame)",
    "ring_trigger": "handle_frame up to the model: ring push + trigger",
    "window": "model input window from the ring",
    "inference": "onnxruntime run",
    "output_check": "output contract check",
    "event_build": "event built",
    "serialise": "JSON line encoded",
    "sink_send": "UDP sink send",
    "total": "**total: frame bytes -> sink send**",
    "daemon_internal": "inside the daemon: frame parsed -> decision (the event's latency_us)",
    "handle_frame_no_decision": "(frames without a decision: handle_frame)",
}


def _targets_lines(res: dict) -> list[str]:
    lines = ["| key | this run | target (at most) | met |", "|---|---|---|---|"]
    for key, target in TARGETS.items():
        value = res.get(key)
        shown = "-" if value is None else f"{value:.2f}" if key in ("paced_over_back_to_back", "shadow_p999_ratio",
                                                                                 "shadow_capture_p999_ratio") else f"{value:,.1f}"
        met = "-" if value is None else "yes" if value <= target else "no"
        lines.append(f"| `{key}` | {shown} | {target:g} | {met} |")
    return lines


RHYTHMS = {"solo": "alone, back to back", "back_to_back": "interleaved, back to back",
           "paced_32hz": "interleaved, paced 32 Hz", "paced_asleep": "alone, paced 32 Hz, asleep until the frame",
           "paced_rehearsed": "alone, paced 32 Hz, rehearsed just before the frame (as the daemon does)",
           "back_to_back_load": "interleaved, back to back, under load"}
"""Rows of the implementation table: ``solo`` gives the absolute figures (the headline), the
interleaved ones the ratios."""


def _implementation_lines(res: dict) -> list[str]:
    lines = ["| implementation, pads | rhythm | median (us) | p99 (us) | p99.9 (us) | n | / graph's (median / p99 / p99.9) |",
             "|---|---|---|---|---|---|---|"]
    for key, pads in (("implementations", "all pads"), ("implementations_distal", "distal pads")):
        imp = res[key]
        for rhythm in RHYTHMS:
            if rhythm not in imp:
                continue
            graph = imp[rhythm]["onnxruntime"]
            for name, s in imp[rhythm].items():
                ratios = " / ".join(f"{s[k] / graph[k]:.2f}" for k in ("p50", "p99", "p999"))
                lines.append(f"| {name}, {pads} | {RHYTHMS[rhythm]} | {fmt_us(s['p50'])} | {fmt_us(s['p99'])} | "
                             f"{fmt_us(s['p999'])} | {s['n']} | {ratios} |")
    lines += ["", "**Alone** (`solo`): the graph in its own warm back-to-back block, nothing else between its "
              "calls, as it runs in the daemon; `onnx_p50_us` and `onnx_p50_us_all_pads` are its median here. "
              "The graph against scikit-learn: `handover bench inference` (results/inference.md).", "",
              "Alone, paced 32 Hz: the graph by itself, one window each sample period. **Asleep until the frame**: "
              "the thread blocks until the window's last frame arrives, as the daemon waits (and as the stage "
              "tables above do). **Rehearsed just before the frame**: the graph run once "
              f"{REHEARSAL_LEAD_S * 1e3:g} ms before the frame, then asleep until it, as the daemon does before a "
              "frame that runs the model (see *Keeping the hot path warm* below)."]
    return lines


def _keep_warm_lines(res: dict) -> list[str]:
    """What each mechanism that keeps the hot path fast buys in this run, against the sample period."""
    period = DEADLINE_US
    paced = res["stages"]["paced_32hz"]["daemon_internal"]
    lines = ["## Keeping the hot path warm: what each mechanism buys", "",
             f"The decision inside the daemon (frame parsed -> decision, paced at 32 Hz, the table above): median "
             f"{fmt_us(paced['p50'])} us, p99.9 {fmt_us(paced['p999'])} us, {100 * paced['p50'] / period:.2f} % and "
             f"{100 * paced['p999'] / period:.2f} % of the {period:.0f} us period. Each row: the mechanism, what it "
             "buys in this run, and whether the daemon keeps it.", "",
             "| mechanism | without (us) | with (us) | buys (us) | share of the period | kept |", "|---|---|---|---|---|---|"]
    cold = res["stages"].get("paced_32hz_not_rehearsed", {}).get("daemon_internal")
    if cold:
        for stat, name in (("p50", "median"), ("p999", "p99.9")):
            a, w = cold[stat], paced[stat]
            lines.append(f"| the model rehearsed once {REHEARSAL_LEAD_S * 1e3:g} ms before a frame that runs it "
                         f"(`runtime/rehearsal.py`; frame parsed -> decision inside the daemon, paced, {name}) | "
                         f"{fmt_us(a)} | {fmt_us(w)} | {fmt_us(a - w)} | {100 * (a - w) / period:.2f} % | yes |")
    for key, pads in (("implementations", "all pads"), ("implementations_distal", "distal pads")):
        imp = res[key]
        if "paced_asleep" in imp and "paced_rehearsed" in imp:
            a, w = imp["paced_asleep"]["onnxruntime"]["p50"], imp["paced_rehearsed"]["onnxruntime"]["p50"]
            lines.append(f"| the same, the graph alone (paced, median, {pads}) | {fmt_us(a)} | {fmt_us(w)} | "
                         f"{fmt_us(a - w)} | {100 * (a - w) / period:.2f} % | yes |")
        if "binding" in imp:
            plain, staged = imp["binding"]["session_run"]["p50"], imp["binding"]["staged"]["p50"]
            lines.append(f"| the window copied to one aligned array first (`LoadedModel.run_trusted`: one answer bit "
                         f"for bit wherever the ring holds it; graph alone, back to back, median, {pads}) | "
                         f"{fmt_us(plain)} | {fmt_us(staged)} | {fmt_us(plain - staged)} | "
                         f"{100 * (plain - staged) / period:.2f} % | yes |")
    heap = res.get("heap")
    if heap:
        lines.append(f"| start-up's objects hidden from the collector (`gc.freeze`, `runtime/heap.py`): a full "
                     f"collection | {fmt_us(heap['full_us'])} | {fmt_us(heap['full_frozen_us'])} | "
                     f"{fmt_us(heap['full_us'] - heap['full_frozen_us'])} | "
                     f"{100 * (heap['full_us'] - heap['full_frozen_us']) / period:.2f} % | yes |")
    young = f"{fmt_us(heap['young_us'])} us" if heap else "microseconds"
    lines += ["", KEEP_WARM_NOTE.format(young=young), ""]
    return lines


KEEP_WARM_NOTE = (
    "The rule: a mechanism stays only if what it buys is worth its lines and its CPU. The rehearsal is one "
    "object (`runtime/rehearsal.py`, read by the daemon's loop) and two detector methods: before a frame that "
    "will run the model (a window's end, an early head's point, every frame in continuous mode) the loop "
    "cuts its read short, runs the model once on the newest window and goes back to sleep; one extra model "
    "run per decision, nothing between events, no spinning: kept. What it replaced (device polling and a "
    "spinning core until the frame, a collector schedule and a receive-path rehearsal in the client: about "
    "1,200 lines across five layers and up to 4 ms of a spinning core per decision) bought little more: "
    "removed. Buffers bound once to onnxruntime (`runtime/bound_run.py`) "
    "bought 5.5 us (distal pads) and 6.8 us (all pads) a decision in the run that decided it (0.02 % of the "
    "period): removed; what was worth keeping from them, one answer bit for bit wherever the ring holds a "
    "window (onnxruntime sums in an order that depends on the input's address), is one copy into an aligned "
    "array (the row above). `gc.freeze` is one call at start-up and takes the long-lived objects out of every "
    "later collection (a full collection inside a decision would otherwise cost the 'without' figure of "
    "this process): kept. Automatic collection stays on: a young collection of 700 fresh objects costs "
    "{young}.")


def _kind(m: dict) -> str:
    """``bow_svm, K=10, W=7, `` for a BoW graph, else the model kind (K and W mean nothing there)."""
    kind = m.get("kind") or "bow_svm"
    return f"{kind}, K={m['K']}, W={m['W']}, " if kind == "bow_svm" else f"{kind}, "


def markdown(res: dict) -> list[str]:
    m = res["model"]
    lines = ["# Latency by stage and end to end (synthetic data)", "",
             f"Deadline: one sample period, {DEADLINE_US:.0f} us at 32 Hz. Model: the default ({_kind(m)}T={m['T']}, "
             f"{m['n_channels']} taxels of pads {m['pads']}, {m['n_nodes']} nodes; {m.get('n_nodes_distal', '?')} on the distal pads) trained "
             "on the simulated protocol (synthetic). The last column says how many times each figure fits into "
             "the deadline.", "", res["note"], "", "## Targets", "", *_targets_lines(res), "",
             "`onnx_p50_us` (distal pads) and `onnx_p50_us_all_pads` are the graph's median alone, one window back to "
             "back (the `alone` rows of the implementation table). "
             "`daemon_p999_us` and `paced_over_back_to_back` (medians) come from the stage table below, paced at "
             "32 Hz; `e2e_*` from the `handover run` process; `rss_mb` is that process's VmRSS.", "",
             "![latency](latency.png)", "", "## Stages: frame bytes -> sink send (this process, the real daemon)", ""]
    for key, title in (("stages", ""), ("stages_load", ", under load")):
        if key not in res:
            continue
        for rhythm in ("back_to_back", "paced_32hz", "continuous_paced_32hz"):
            table = res[key].get(rhythm)
            if table is None:
                continue
            lines += [f"### {RHYTHM_TITLES[rhythm]}{title}", "", *HEAD]
            lines += [_row(STAGE_TITLES[name], s) for name, s in table.items() if s["n"]]
            lines.append("")
    lines += ["Paced: the frame that completes each window arrives one sample period after the frame before it "
              "(the process idle in between, as in service); the frames between windows are fed back to back. "
              "Continuous mode: every frame arrives one sample period after the one before, and every frame is a "
              "decision; the graph is the default's, its metadata naming "
              f"a dormant class (`{res['model'].get('continuous_dormant', '?')}`) so that continuous mode serves it: "
              "what the classes mean does not change how long a decision takes. Its rows up to the output check "
              "and `frame parsed -> decision` count every frame's decision (the json's `continuous_daemon_p50_us` "
              "and `continuous_daemon_p999_us`, not targets); the rows after the check only the "
              "decisions continuous mode's report rule sent as an event (`[continuous]` in the config: a class "
              "that won `confirm_frames` frames in a row; docs/DORMANT.md), so their n is small; its "
              "`frames without a decision` are the first T - 1 frames, before the first window is full. "
              "Under load: two busy-loop processes, one per core.", "",
              *shadow_lines(res.get("shadow")), "## The graph alone (one window)", "",
              *_implementation_lines(res), "", *_keep_warm_lines(res), *_limit_lines(res),
              "## End to end (emulator process -> loopback TCP -> `handover run` -> UDP -> listener)", "", *HEAD]
    for key, title in (("e2e_32hz", "end to end at 32 Hz"), ("e2e_32hz_load", "end to end at 32 Hz, under load"),
                       ("e2e_32hz_load_normal", "end to end at 32 Hz, under load, normal scheduling")):
        if key in res:
            e = res[key]
            lines.append(_row(title, e["e2e_us"]))
            lines.append(_row(f"({title}: inside the daemon, frame parsed -> decision)", e["daemon_internal_us"]))
    lines += [""]
    for key in ("e2e_32hz", "e2e_32hz_load", "e2e_32hz_load_normal"):
        if key in res:
            e = res[key]
            lines.append(f"- {key}: realtime_priority {e.get('realtime_priority', 0)}, {e['windows_sent']} windows sent (one every {res['window_period_frames']} frames), "
                         f"{e['events']} events received ({e['unmatched']} not matched to a frame), "
                         f"{e['missed_deadline']} over the deadline; daemon VmRSS {e['rss_mb'] or 0:.1f} MB.")
    lines += ["", "Under load = two busy-loop processes, one per core, during the run." if "e2e_32hz_load" in res
              else "No run under load (add --load).", "",
              "Scheduling: the daemon runs its hot thread at the config's `realtime_priority` (SCHED_FIFO "
              f"{DEFAULT_PRIORITY} by default; runtime/realtime.py says why, deploy/handover.service permits it), the "
              "emulator and the listener run at the same priority (a real controller is hardware, the robot's "
              "receiver is not ours to measure), and so does this process's thread during the stage tables. "
              f"This run: {res.get('scheduling', 'not recorded')}. The `normal scheduling` row runs all three "
              "at `realtime_priority = 0` for comparison.", "", *early_lines(res.get("early_frames"))]
    return lines


def plot(res: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    table = res["stages"]
    names = [n for n in (*stages.STAGES, "total") if table["paced_32hz"][n]["n"]]
    fig, ax = plt.subplots(figsize=(8, 5))
    y = np.arange(len(names))
    for dy, rhythm, stat, label in ((-0.3, "back_to_back", "p50", "back to back, median"),
                                    (-0.1, "paced_32hz", "p50", "paced 32 Hz, median"),
                                    (0.1, "paced_32hz", "p99", "paced 32 Hz, p99"),
                                    (0.3, "paced_32hz", "p999", "paced 32 Hz, p99.9")):
        ax.barh(y + dy, [table[rhythm][n][stat] for n in names], 0.2, label=label)
    ax.set_xscale("log")
    ax.set_yticks(y, names)
    ax.invert_yaxis()
    ax.set_xlabel("microseconds (log scale)")
    ax.set_title("Decision stages, frame bytes -> sink send (synthetic stream)")
    ax.legend(fontsize=8)
    ax.grid(True, axis="x", which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
