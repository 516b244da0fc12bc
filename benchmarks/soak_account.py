"""The soak benchmark's bookkeeping: what was sent, what the daemon handled, which losses fall
inside an injected fault, which events were expected and arrived, and when the watchdog would
have fired. Pure functions over the run's logs (see benchmarks/soak.py for the rules)."""

from __future__ import annotations

import bisect
import math
import statistics

MARGIN_S = 0.25
"""Frames sent this close before a fault's start or after its recovery count as inside it."""
SETTLE_S = 5.0
"""Frames sent in the first seconds after READY are left out (the first connect is not a fault)."""
RECOVERY_LIMIT_S = 120.0


def which_sent(sent: list[tuple[int, float, int]], stamps, times) -> dict[int, float]:
    """Which frame of ``sent`` (its index) each arrival (device stamp, time) was -> the first arrival.

    A stamp names no frame of the run alone: a power-cycled controller restarts its clock (every TCP
    drop is a power cycle), so stamps recur, a boot (8 s) or more apart. An arrival was the last frame
    sent with its stamp before it arrived."""
    sends: dict[int, tuple[list[int], list[float]]] = {}
    for k, (stamp, t_sent, _) in enumerate(sent):
        ks, ts = sends.setdefault(stamp, ([], []))
        ks.append(k)
        ts.append(t_sent)
    out: dict[int, float] = {}
    for stamp, t in zip(stamps, times, strict=True):
        ks, ts = sends.get(int(stamp), ((), ()))
        j = bisect.bisect_right(ts, t) - 1
        if j >= 0:
            out.setdefault(ks[j], t)
    return out


def fault_windows(faults, sent: list[tuple[int, float, int]], handled: dict[int, float]) -> list[tuple[float, float]]:
    """Set each fault's ``recovered_at`` (first frame handled that was sent after the fault
    ended) and return the send-time windows inside which a loss is the fault's. ``handled``: index
    in ``sent`` -> arrival time (``which_sent``)."""
    fresh = sorted((sent[k][1], t_recv) for k, t_recv in handled.items())
    sent_times = [t for t, _ in fresh]
    windows = []
    for f in faults:
        k = bisect.bisect_right(sent_times, f.end)
        later = [t_recv for _, t_recv in fresh[k : k + 64]]
        f.recovered_at = min(later) if later else None
        if f.recovered_at is not None and f.recovered_at - f.end > RECOVERY_LIMIT_S:
            f.recovered_at = None
        stop = f.recovered_at if f.recovered_at is not None else math.inf
        windows.append((f.start - MARGIN_S, stop + MARGIN_S))
    return windows


def _inside(t: float, windows: list[tuple[float, float]]) -> bool:
    return any(a <= t <= b for a, b in windows)


def frame_figures(sent, handled, windows, t0: float, t_end: float) -> dict:
    """frames_expected, lost inside and outside the injected faults (with the first few outside)."""
    counted = [k for k, (_, t, _) in enumerate(sent) if t0 + SETTLE_S <= t <= t_end - 2.0]
    lost = [sent[k][1] for k in counted if k not in handled]
    outside = [round(t - t0, 2) for t in lost if not _inside(t, windows)]
    return {"frames_expected": len(counted), "frames_handled": len(counted) - len(lost),
            "frames_lost": len(lost), "frames_lost_inside_injected_faults": len(lost) - len(outside),
            "frames_lost_outside_injected_faults": len(outside), "lost_outside_examples": outside[:10]}


def event_figures(sent, handled, windows, events, reference: set[int], n_frames: int, t0: float,
                  t_end: float, history: int) -> dict:
    """events_expected (reference decisions with a clean, fully handled history), events_lost.
    ``reference`` holds recording indices: a sent frame's is its sequence number (the third item)
    modulo ``n_frames``, not its place in ``sent`` (the frames of an outage are skipped, not sent)."""
    reported = which_sent(sent, [int(ev.get("device_time_ms", -1)) for _, ev in events], [t for t, _ in events])
    expected = lost = 0
    missing: list[float] = []
    for k, (_, t, seq) in enumerate(sent):
        if seq % n_frames not in reference or k < history or not (t0 + SETTLE_S <= t <= t_end - 2.0):
            continue
        if any(j not in handled or _inside(sent[j][1], windows) for j in range(k - history, k + 1)):
            continue
        expected += 1
        if k not in reported:
            lost += 1
            missing.append(round(t - t0, 2))
    unexpected = sum(1 for k in reported if sent[k][2] % n_frames not in reference)
    return {"events_reported": len(events), "events_expected": expected, "events_lost": lost,
            "events_lost_at_s": missing[:10], "events_outside_reference": unexpected}


def fault_figures(faults, t0: float) -> dict:
    by_kind: dict[str, dict] = {}
    recoveries = []
    for f in faults:
        k = by_kind.setdefault(f.kind, {"injected": 0, "recovered": 0, "max_recovery_s": 0.0})
        k["injected"] += 1
        if f.recovered_at is not None:
            k["recovered"] += 1
            r = max(0.0, f.recovered_at - f.end)
            k["max_recovery_s"] = round(max(k["max_recovery_s"], r), 3)
            recoveries.append(r)
    return {"faults_injected": len(faults), "faults_recovered": sum(v["recovered"] for v in by_kind.values()),
            "max_recovery_s": round(max(recoveries), 3) if recoveries else None,
            "median_recovery_s": round(statistics.median(recoveries), 3) if recoveries else None,
            "faults_by_kind": by_kind,
            "fault_log": [{"kind": f.kind, "t": round(f.start - t0, 1),
                           "recovery_s": None if f.recovered_at is None else round(f.recovered_at - f.end, 3)}
                          for f in faults]}


def watchdog_figures(pings: list[float], faults, t0: float, t_end: float, limit_s: float) -> dict:
    """Would systemd's watchdog have fired, and was each injected hang caught?"""
    from benchmarks.soak_rig import ping_intervals, watchdog_gaps

    gaps = watchdog_gaps(pings, t0, t_end, limit_s)
    hangs = [f for f in faults if f.kind == "hang"]

    def overlaps(gap, f) -> bool:
        return gap[0] < f.end and gap[1] > f.start

    healthy = [g for g in gaps if not any(overlaps(g, f) for f in hangs)]
    caught = sum(1 for f in hangs if any(overlaps(g, f) for g in gaps))
    return {"watchdog_would_fire": len(gaps), "watchdog_would_fire_while_healthy": len(healthy),
            "hangs_injected": len(hangs), "hangs_caught_by_watchdog": caught,
            "watchdog_pings": len(pings), "longest_ping_gap_outside_hangs_s": round(max(
                (b - a for a, b in ping_intervals(pings, t0, t_end) if not any(overlaps((a, b), f) for f in hangs)),
                default=0.0), 3)}


def rss_figures(samples: list[tuple[float, float]], seconds: float) -> dict:
    """RSS growth: the median of the last tenth of the run against the median of its second tenth
    (after start-up, model loading and the first reconnects)."""
    ok = [(t, v) for t, v in samples if v == v]
    if len(ok) < 4:
        return {"rss_growth_mb": None, "rss_samples": len(ok)}
    early = [v for t, v in ok if 0.1 * seconds <= t <= 0.2 * seconds] or [ok[len(ok) // 4][1]]
    late = [v for t, v in ok if t >= 0.9 * seconds] or [ok[-1][1]]
    base, end = statistics.median(early), statistics.median(late)
    return {"rss_growth_mb": round(end - base, 2), "rss_baseline_mb": round(base, 1), "rss_end_mb": round(end, 1),
            "rss_max_mb": round(max(v for _, v in ok), 1), "rss_first_mb": round(ok[0][1], 1), "rss_samples": len(ok)}
