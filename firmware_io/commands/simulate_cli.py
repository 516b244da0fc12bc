"""``handover simulate``: write the paper's protocol (or a scripted session) as synthetic recordings."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from firmware_io.commands.errors import DEVICE_ERROR, fail
from firmware_io.commands.out_folder import out_folder_problem

__all__ = ["add_arguments", "main"]

COMMAND = "simulate"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="folder to write recordings into")
    parser.add_argument("--seed", type=int, default=0, help="random seed (same seed, same bytes)")
    parser.add_argument("--subjects", type=int, default=5, help="number of subjects (protocol)")
    parser.add_argument("--runs", type=int, default=5, help="runs per pose/object/action (protocol)")
    parser.add_argument("--session", type=int, metavar="N_EVENTS", default=None,
                        help="write a free-running session of N scripted events instead (plus its script as JSON)")


def main(args: argparse.Namespace) -> int:
    from firmware_io.recordings.recording import RecordingError
    from firmware_io.sim import demo_script, simulate_session, trial_counts, write_protocol

    problem = out_folder_problem(args.out)
    if problem:
        return fail(COMMAND, problem)
    start = time.perf_counter()
    try:
        if args.session is not None:
            script = demo_script(n_events=args.session, seed=args.seed)
            rec = simulate_session(script, seed=args.seed)
            args.out.mkdir(parents=True, exist_ok=True)
            path = rec.save(args.out / f"session_seed{args.seed}.hrec")
            script_path = args.out / f"session_seed{args.seed}.json"
            script_path.write_text(json.dumps([e.to_dict() for e in script], indent=1))
            print(f"wrote {path} (synthetic session: {len(script)} events, {rec.n_frames} frames, "
                  f"{rec.timestamps[-1]:.1f} s) and {script_path} in {time.perf_counter() - start:.1f} s")
            return 0
        paths = write_protocol(args.out, seed=args.seed, n_subjects=args.subjects, runs=args.runs)
    except (ValueError, OSError, RecordingError) as exc:
        return fail(COMMAND, str(exc), DEVICE_ERROR)
    from firmware_io.recordings.recording import Recording

    recs = [Recording.load(p) for p in paths]
    counts = trial_counts(recs)
    for p, r in zip(paths, recs, strict=True):
        print(f"wrote {p} ({len(r.trials)} trials, {r.n_frames} frames)")
    total = sum(counts.values())
    print(f"synthetic protocol: {total} trials ({', '.join(f'{k} {v}' for k, v in counts.items())}), "
          f"seed {args.seed}, {time.perf_counter() - start:.1f} s")
    return 0
