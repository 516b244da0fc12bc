"""Serving with a candidate in shadow against serving alone, in one process: the serving decision's p99.9.

The daemon's hot path as the stage tables feed it (``latency_stages.feed``, paced at 32 Hz), each
decision offered to the daemon's ``Shadow`` (runtime/shadow.py). The candidate is a copy of the serving
graph under another model id: a retrained model of the same kind costs as much. Blocks of paced
decisions alternate (without, with, with, without, ...) so a change of the shared machine's load meets
both cases alike, and each case's decisions are pooled. ``shadow + capture`` adds the daemon's field
capture (runtime/capture.py: a ring copy of every frame on the hot path, a window's copy once its
post-report frames are in, written by its own thread).
"""

from __future__ import annotations

from pathlib import Path

from trainer.bench import latency_stages as stages
from trainer.measure import percentiles, with_metadata

CASES = ("serving", "shadow", "shadow + capture")
"""The cases measured, the first the reference (``_case_options`` says what each adds)."""
TARGET_RATIO = 1.2
"""The serving decision's p99.9 with a shadow (and capture) may be at most this times that without."""


def candidate_folder(model_path: Path, work: Path) -> Path:
    """A shadow folder holding the candidate: the serving graph under another id (its metadata names it)."""
    folder = work / "shadow"
    folder.mkdir(parents=True, exist_ok=True)
    out = with_metadata(model_path, folder / "candidate.onnx",
                        lambda meta: meta.setdefault("training", {}).update(note="shadow candidate (timing only)"))
    out.chmod(0o644)
    return folder


def _case_options(case: str, folder: Path) -> dict:
    if case == "serving":
        return {}
    return {"shadow": folder, **({"capture": folder.parent / "field"} if "capture" in case else {})}


def shadow_cases(model, recording, paced_decisions: int, work: Path, blocks: int = 8) -> dict:
    """Frame parsed -> decision for each of ``CASES`` over ``paced_decisions`` paced decisions each, in
    ``blocks`` alternating blocks; the p99.9 ratio of each case against the first, and the shadow's counts."""
    folder = candidate_folder(Path(model.path), work)
    packets = stages._encoded(recording)
    due = stages.decision_frames(model, recording)
    per_block = max(1, paced_decisions // blocks)
    last = sorted(due)[min(len(due), per_block) - 1] if due else 0
    raw: dict[str, list[list[float]]] = {case: [] for case in CASES}
    counts: dict[str, list[dict]] = {case: [] for case in CASES}
    captured: list[dict] = []
    for block in range(blocks):
        for case in (CASES if block % 2 == 0 else CASES[::-1]):
            block_raw: list[float] = []
            table = stages.feed(model, recording, packets[: last + 1], frozenset(due), raw=block_raw,
                                **_case_options(case, folder))
            raw[case].append(block_raw)
            if "shadow" in table:
                counts[case].append(table["shadow"])
            if "capture" in table:
                captured.append(table["capture"])
    out: dict = {case: percentiles([x for b in raw[case] for x in b]) for case in CASES}
    reference = out[CASES[0]]["p999"]
    out["p999_ratio"] = {case: out[case]["p999"] / reference for case in CASES[1:]}
    out["shadow_counts"] = {case: {k: sum(c[k] for c in counts[case]) for k in ("windows_compared", "windows_dropped")}
                            for case in CASES if counts[case]}
    out["capture_counts"] = {**{k: sum(c[k] for c in captured) for k in ("capture_events", "capture_dropped",
                                                                         "capture_errors")},
                             "capture_bytes": captured[-1]["capture_bytes"] if captured else 0}
    alone = raw[CASES[0]]  # the reference against itself: its odd blocks over its even ones, the figure's noise
    halves = [percentiles([x for b in alone[i::2] for x in b])["p999"] for i in (0, 1)]
    out["null_p999_ratio"] = halves[1] / halves[0] if blocks > 1 and halves[0] else None
    out["blocks"], out["target_ratio"] = blocks, TARGET_RATIO
    return out


def markdown_lines(res: dict | None) -> list[str]:
    """The section of results/latency.md (nothing when the run did not measure it)."""
    if not res:
        return []
    lines = ["## Serving with a candidate in shadow", "",
             "The serving decision (frame parsed -> decision inside the daemon, paced at 32 Hz as in the stage tables) "
             f"without and with a candidate model in `[model] shadow` (runtime/shadow.py), in this process: {res['blocks']} "
             "blocks that alternate the cases, pooled. The candidate is the serving graph under another id, so it costs "
             "a decision's worth of CPU in its own thread after every serving decision.", "",
             "| case | median (us) | p99 (us) | p99.9 (us) | max (us) | n | p99.9 / serving alone |", "|---|---|---|---|---|---|---|"]
    for case in CASES:
        s = res[case]
        ratio = res["p999_ratio"].get(case, 1.0)
        lines.append(f"| {case.replace('serving', 'serving alone') if case == 'serving' else 'serving with a ' + case} | "
                     f"{s['p50']:,.0f} | {s['p99']:,.0f} | {s['p999']:,.0f} | {s['max']:,.0f} | {s['n']} | {ratio:.2f} |")
    lines += [""]
    if capture := res.get("capture_counts"):
        lines.append(f"- shadow + capture: {capture['capture_events']} decided windows captured "
                     f"({capture['capture_bytes'] / 1e6:.1f} MB in the folder at the end), {capture['capture_dropped']} "
                     f"dropped, {capture['capture_errors']} write errors.")
    for case, c in res["shadow_counts"].items():
        lines.append(f"- {case}: the candidate decided {c['windows_compared']} windows in its thread, "
                     f"{c['windows_dropped']} dropped (a full queue).")
    verdicts = [f"{case} {r:.2f}x, {'met' if r <= res['target_ratio'] else 'not met'}"
                for case, r in res["p999_ratio"].items()]
    alone = res["serving"]
    spread = "; ".join(f"{case}: median {res[case]['p50'] / alone['p50']:.2f}x, p99 {res[case]['p99'] / alone['p99']:.2f}x"
                       for case in CASES[1:])
    lines += ["", f"Target: serving p99.9 with a shadow (and capture) at most {res['target_ratio']:g}x without: "
              f"{'; '.join(verdicts)} ({spread}). A p99.9 of {alone['n']} decisions is their few slowest, which the "
              "machine's other work decides (the load average above): a ratio below 1 says the case did not measurably "
              "slow the serving decision, not that it sped it up." + _null_sentence(res), ""]
    return lines


def _null_sentence(res: dict) -> str:
    """How far the reference's p99.9 moves against itself in the same run (its odd blocks over its even ones)."""
    null = res.get("null_p999_ratio")
    if null is None:
        return ""
    return (f" The same measure of serving alone against itself in this run (its odd blocks over its even ones, "
            f"{res[CASES[0]]['n'] // 2} decisions each): {null:.2f}x, the noise any ratio above carries.")
