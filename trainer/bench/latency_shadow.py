"""Serving with a candidate in shadow against serving alone, in one process: the serving decision's p99.9.

The daemon's hot path as the stage tables feed it (``latency_stages.feed``, paced at 32 Hz), each
decision offered to the daemon's ``Shadow`` (runtime/shadow.py). The candidate is a copy of the serving
graph under another model id: a retrained model of the same kind costs as much. Blocks of paced
decisions alternate (without, with, with, without, ...) so a change of the shared machine's load meets
both cases alike, and each case's decisions are pooled. ``CASES`` is where a case joins: a ``shadow +
capture`` case needs the daemon's ``[capture] folder``, not on main when this was written.
"""

from __future__ import annotations

from pathlib import Path

from trainer.bench import latency_stages as stages
from trainer.measure import percentiles, with_metadata

CASES = ("serving", "shadow")
"""The cases measured, the first the reference. The hook for field capture: add "shadow + capture" here
and in ``_case_options`` once ``[capture] folder`` is on main."""
TARGET_RATIO = 1.2
"""The serving decision's p99.9 with a shadow may be at most this times that without (issue #39)."""


def candidate_folder(model_path: Path, work: Path) -> Path:
    """A shadow folder holding the candidate: the serving graph under another id (its metadata names it)."""
    folder = work / "shadow"
    folder.mkdir(parents=True, exist_ok=True)
    out = with_metadata(model_path, folder / "candidate.onnx",
                        lambda meta: meta.setdefault("training", {}).update(note="shadow candidate (timing only)"))
    out.chmod(0o644)
    return folder


def _case_options(case: str, folder: Path) -> dict:
    return {"shadow": folder} if case == "shadow" else {}


def shadow_cases(model, recording, paced_decisions: int, work: Path, blocks: int = 4) -> dict:
    """Frame parsed -> decision for each of ``CASES`` over ``paced_decisions`` paced decisions each, in
    ``blocks`` alternating blocks; the p99.9 ratio of each case against the first, and the shadow's counts."""
    folder = candidate_folder(Path(model.path), work)
    packets = stages._encoded(recording)
    due = stages.decision_frames(model, recording)
    per_block = max(1, paced_decisions // blocks)
    last = sorted(due)[min(len(due), per_block) - 1] if due else 0
    raw: dict[str, list[float]] = {case: [] for case in CASES}
    counts: dict[str, list[dict]] = {case: [] for case in CASES}
    for block in range(blocks):
        for case in (CASES if block % 2 == 0 else CASES[::-1]):
            table = stages.feed(model, recording, packets[: last + 1], frozenset(due), raw=raw[case],
                                **_case_options(case, folder))
            if "shadow" in table:
                counts[case].append(table["shadow"])
    out: dict = {case: percentiles(raw[case]) for case in CASES}
    reference = out[CASES[0]]["p999"]
    out["p999_ratio"] = {case: out[case]["p999"] / reference for case in CASES[1:]}
    out["shadow_counts"] = {case: {k: sum(c[k] for c in counts[case]) for k in ("windows_compared", "windows_dropped")}
                            for case in CASES if counts[case]}
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
    for case, c in res["shadow_counts"].items():
        lines.append(f"- {case}: the candidate decided {c['windows_compared']} windows in its thread, "
                     f"{c['windows_dropped']} dropped (a full queue).")
    ratio = res["p999_ratio"].get("shadow")
    met = "met" if ratio is not None and ratio <= res["target_ratio"] else "not met"
    lines += ["", f"Target: serving p99.9 with a shadow at most {res['target_ratio']:g}x without: {ratio:.2f}x, {met}. "
              "`shadow + capture` is not measured: `[capture] folder` (issue #39 item 2) was not in the daemon when "
              "this ran; `CASES` in trainer/bench/latency_shadow.py is where it joins.", ""]
    return lines
