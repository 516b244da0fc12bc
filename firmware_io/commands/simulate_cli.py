"""``handover simulate``: write the paper's protocol (or a scripted session) as synthetic recordings."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from firmware_io.commands.options import add_lab, add_out, add_seed, out_folder, positive_int
from firmware_io.errors import DeviceFailure

__all__ = ["add_arguments", "main"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_out(parser, "folder to write recordings into", required=True, type=Path)
    add_seed(parser, help="random seed (same seed, same bytes)")
    add_lab(parser)
    parser.add_argument("--subjects", type=positive_int, default=5, help="number of subjects (protocol)")
    parser.add_argument("--runs", type=positive_int, default=5, help="runs per pose/object/action (protocol)")
    parser.add_argument("--session", type=int, metavar="N_EVENTS", default=None,
                        help="write a free-running session of N scripted events instead (plus its script as JSON)")


def main(args: argparse.Namespace) -> int:
    from firmware_io.sim import demo_script, simulate_session, trial_counts, write_protocol
    from firmware_io.sim.lab import get_lab

    out_folder(args.out)
    start = time.perf_counter()
    try:
        if args.session is not None:
            script = demo_script(n_events=args.session, seed=args.seed, objects=get_lab(args.lab).objects)
            rec = simulate_session(script, seed=args.seed, lab=args.lab)
            args.out.mkdir(parents=True, exist_ok=True)
            path = rec.save(args.out / f"session_seed{args.seed}.hrec")
            script_path = args.out / f"session_seed{args.seed}.json"
            script_path.write_text(json.dumps([e.to_dict() for e in script], indent=1))
            print(f"wrote {path} (synthetic session: {len(script)} events, {rec.n_frames} frames, "
                  f"{rec.timestamps[-1]:.1f} s) and {script_path} in {time.perf_counter() - start:.1f} s")
            return 0
        paths = write_protocol(args.out, seed=args.seed, n_subjects=args.subjects, runs=args.runs, lab=args.lab)
    except (ValueError, OSError) as exc:  # a recording error too: the simulator wrote what it cannot read
        raise DeviceFailure(str(exc)) from exc
    from firmware_io.recordings.recording import Recording

    recs = [Recording.load(p) for p in paths]
    counts = trial_counts(recs)
    for p, r in zip(paths, recs, strict=True):
        print(f"wrote {p} ({len(r.trials)} trials, {r.n_frames} frames)")
    total = sum(counts.values())
    print(f"synthetic protocol: {total} trials ({', '.join(f'{k} {v}' for k, v in counts.items())}), "
          f"seed {args.seed}, lab {args.lab}, {time.perf_counter() - start:.1f} s")
    return 0
