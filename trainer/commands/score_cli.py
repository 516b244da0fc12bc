"""``handover score EVENTS.jsonl SCRIPT``: how a captured event stream did against a scripted session.

EVENTS is what the daemon sent (its stdout, or a UDP listener's lines; ``-`` reads stdin), SCRIPT
what ``handover emulate --script-out`` wrote. The summary is the demo's (right, wrong, missed,
outside any scripted event, onset to report), computed by the same rule
(``trainer.session_score``). Needs no extra: numpy only.
"""

from __future__ import annotations

import argparse
import json
import sys

from firmware_io.commands.options import add_json
from firmware_io.errors import HandoverError

__all__ = ["add_arguments", "main"]

MAX_EVENTS_CHARS = 32 << 20
"""The most event text one score reads: ``MAX_EVENT_LINES`` decision lines take about 20 MiB."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("events", metavar="EVENTS.jsonl", help="the daemon's event lines ('-': stdin)")
    parser.add_argument("script", metavar="SCRIPT", help="the file handover emulate --script-out wrote")
    parser.add_argument("--instance", default=None, help="score only the lines of this daemon instance")
    add_json(parser)


def main(args: argparse.Namespace) -> int:
    from firmware_io.emulator.script_file import read_script
    from trainer.session_score import (
        capture_problem,
        decisions_from_lines,
        lines_of,
        not_played_line,
        outcome_summary,
        score,
        summary_lines,
    )

    script = read_script(args.script)
    try:
        if args.events == "-":
            text = sys.stdin.read(MAX_EVENTS_CHARS + 1)
        else:
            with open(args.events, encoding="utf-8", errors="replace") as f:
                text = f.read(MAX_EVENTS_CHARS + 1)
    except OSError as exc:
        raise HandoverError(f"{args.events}: cannot read ({exc.strerror or exc})") from None
    if len(text) > MAX_EVENTS_CHARS:  # /dev/zero filled the memory
        raise HandoverError(f"{args.events}: over {MAX_EVENTS_CHARS >> 20} MiB of event lines; score a part of the "
                            "capture (e.g. the lines of one session)")
    capture = decisions_from_lines(lines_of(text), script, args.instance)
    if not script.trials:
        raise HandoverError(f"{args.script}: the session has no scripted events to score against")
    if problem := capture_problem(capture, script):
        raise HandoverError(f"{args.events}: {problem}")
    decisions, skipped = capture.decisions, capture.skipped
    o = score(decisions, script)
    summary = {"synthetic": script.synthetic, "decisions": len(decisions), "lines_skipped": skipped,
               "passes": o["passes"], **outcome_summary(o)}
    unplayed = not_played_line(o, args.events)
    if args.json:
        if unplayed:
            print(f"handover score: {unplayed}", file=sys.stderr, flush=True)
        print(json.dumps(summary))
        return 0
    kind = "synthetic session" if script.synthetic else "session"
    passes = f", {o['passes']} passes of the script" if o["passes"] > 1 else ""
    print(f"score ({kind}; {len(decisions)} decisions{passes}"
          + (f"; {skipped} lines were not event lines" if skipped else "") + ")")
    for line in summary_lines(summary):
        print(line)
    if unplayed:
        print(f"  {unplayed}")
    return 0
