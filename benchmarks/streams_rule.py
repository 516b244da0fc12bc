"""Continuous mode's report rule, chosen by the streams bench on validation streams of its own seed.

The model's per-frame decisions are computed once (batched, ``streams_eval.frame_decisions``) and
every rule of ``GRID`` runs offline on them with the daemon's own ``ContinuousDecision``
(``streams_eval.apply_rule``; the daemon's replay agrees with it, tested). The chosen rule is what
``[continuous]`` ships with (runtime/config_keys.py); the bench says whether the two agree.
"""

from __future__ import annotations

import itertools

GRID = {"confirm_frames": (4, 6, 8, 10, 12), "min_margin": (0.0, 0.5), "rearm_frames": (0, 4, 16),
        "gap_frames": (0, 1, 2, 4), "vote": (False, True)}
"""Rules tried (``vote`` and ``gap_frames``: runtime/decision.py)."""
PREVIOUS = {"confirm_frames": 8, "min_margin": 0.0, "rearm_frames": 4, "gap_frames": 0, "vote": False}
"""The rule shipped before this choice (chosen for an earlier model, results/dormant.md): shown for comparison."""
RULE_EVENTS = 200
"""Events in the rule's validation mixed stream: 60 hold too few holds (15) to tell rules apart."""
CRITERION = ("utility = right first reports - wrong first reports - duplicates - false events, on a validation mixed "
             f"stream of {RULE_EVENTS} events plus the validation idle stream (synthetic, validation seed); ties: the "
             "shorter median onset-to-report, then the simpler rule (smallest confirm + rearm + gap + 4 x margin + vote)")


def rank(row: dict) -> tuple:
    """CRITERION as a sort key (larger is better)."""
    return (row["utility"], -(row["delay_median_frames"] or 1e9),
            -(row["confirm_frames"] + row["rearm_frames"] + row["gap_frames"] + 4 * row["min_margin"] + row["vote"]))


def choose_rule(model, seed: int, idle_recs: list, say) -> dict:
    """Every rule of GRID on the validation streams (``seed``); the best by CRITERION, and the shipped rule's row."""
    from firmware_io.sim import constants as K
    from firmware_io.sim import demo_script
    from firmware_io.sim.idle import simulate_mixed
    from runtime.config import ContinuousConfig
    from trainer import streams_eval as se

    period = K.FRAME_PERIOD_S
    say(f"streams: continuous report rule: validation mixed stream of {RULE_EVENTS} events (synthetic, seed {seed}) ...")
    mixed = simulate_mixed(demo_script(RULE_EVENTS, seed=seed, gap=(10.0, 20.0)), seed=seed)
    truths = se.truths_of(mixed)
    fd_mixed = se.frame_decisions(mixed, model)
    fd_idle = [se.frame_decisions(rec, model) for rec in idle_recs]
    idle_hours = sum(rec.n_frames for rec in idle_recs) * period / 3600.0
    rows = []
    for values in itertools.product(*GRID.values()):
        rule = dict(zip(GRID, values, strict=True))
        sm = se.score(se.apply_rule(*fd_mixed, model.meta, rule), truths, mixed.n_frames, period)
        false = sm["false_events"] + sum(len(se.apply_rule(*fd, model.meta, rule)) for fd in fd_idle)
        hold = sm["per_action"].get("hold", {"n": 0, "correct": 0})
        rows.append({**rule, "correct": sm["correct"], "wrong": sm["wrong_class"], "missed": sm["missed"],
                     "duplicates": sm["duplicates"], "false_events": false,
                     "hold_recall": hold["correct"] / hold["n"] if hold["n"] else None,
                     "delay_median_frames": (sm["delay_frames"] or {}).get("median"),
                     "utility": sm["correct"] - sm["wrong_class"] - sm["duplicates"] - false})
    rows.sort(key=rank, reverse=True)
    chosen = {k: rows[0][k] for k in GRID}
    shipped = {k: getattr(ContinuousConfig(), k) for k in GRID}
    say(f"streams: continuous report rule chosen on validation: {chosen} (utility {rows[0]['utility']})")
    return {"chosen": chosen, "shipped": shipped, "criterion": CRITERION, "grid": GRID, "best": rows[:10],
            "shipped_row": next((r for r in rows if all(r[k] == shipped[k] for k in GRID)), None),
            "previous_row": next((r for r in rows if all(r[k] == PREVIOUS[k] for k in GRID)), None),
            "streams": {"seed": seed, "events": len(truths), "mixed_hours": mixed.n_frames * period / 3600.0,
                        "idle_hours": idle_hours}}
