"""``handover import``: convert .dsa files and ROS bags to ``.hrec`` recordings.

One line per source (frames, duration, rate); a bad source costs one error line, the rest
are still converted, and the exit code is non-zero if any failed. A folder given as a
source is searched for every importable file below it. A file already in ``--out`` under the
same name is replaced only by the same frames (importing again); another recording lands beside it.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from firmware_io.commands.options import add_out, out_folder
from firmware_io.errors import HandoverError

__all__ = ["add_arguments", "main"]

PROG = "handover import"
IDLE_SOURCES = ("open", "quiet", "grasp", "release", "arm_move", "regrasp")
"""``firmware_io.recordings.idle_stretches.SOURCES`` (tested equal; argparse needs them before any import)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "sources",
        nargs="+",
        metavar="SRC",
        help=".dsa file, ROS 1 .bag, ROS 2 bag folder, or a folder to search for them",
    )
    add_out(parser, "folder for the .hrec files", required=True, type=Path)
    parser.add_argument(
        "--pads", default=None, help="keep only these pads (all, distal, proximal, thumb-distal, 1,3,5, ...)"
    )
    parser.add_argument("--topic", default=None, help="bag topic (default: the only TactileSensor topic)")
    parser.add_argument("--idle", default=None, choices=IDLE_SOURCES, metavar="WHAT",
                        help="mark each imported recording as idle (nobody touched the object) and say what was going "
                        f"on: {', '.join(IDLE_SOURCES)}; handover train cuts dormant windows from it")
    parser.add_argument("--subject", default=None,
                        help="with --idle: the subject (or session) the recording belongs to, so leave-one-out "
                        "holds it out with that subject (default: its file name)")


def output_names(sources: list[tuple[Path, Path]]) -> list[str]:
    """A distinct file stem per source: its own stem, with parent folders added where stems clash.

    ``sources`` holds ``(source, base)`` pairs; parts are taken from the path relative to base
    (a folder the user named) so names stay short.
    """

    def parts(src: Path, base: Path) -> list[str]:
        try:
            rel = src.relative_to(base)
        except ValueError:
            rel = Path(src.name)
        chain = list(rel.with_suffix("").parts) if rel.parts else [src.stem]
        return [re.sub(r"[^A-Za-z0-9._-]+", "_", p).strip("_") or "x" for p in chain]

    chains = [parts(s, b) for s, b in sources]
    depth = [1] * len(chains)
    while True:
        names = ["-".join(c[-d:]) for c, d in zip(chains, depth, strict=True)]
        clash = {n for n in names if names.count(n) > 1}
        grow = [i for i, n in enumerate(names) if n in clash and depth[i] < len(chains[i])]
        if not grow:
            break
        for i in grow:
            depth[i] += 1
    seen: dict[str, int] = {}
    out = []
    for n in names:  # still equal (same relative path from different bases): number them
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}-{seen[n]}")
    return out


def _free_target(out: Path, name: str, recording) -> Path:
    """Where ``recording`` goes in ``out``: ``name.hrec``, unless that holds another recording (an
    earlier import of another file of the same name, a recorded session), then ``name-2.hrec``, ...;
    a file holding the same frames is replaced (importing again, e.g. with ``--idle``, loses nothing)."""
    import numpy as np

    from firmware_io.recordings.recording import SUFFIX, Recording, RecordingError

    target, k = out / f"{name}{SUFFIX}", 1
    while target.exists() or target.is_symlink():
        try:
            old = Recording.load(target)
        except (RecordingError, OSError, ValueError):
            old = None
        if old is not None and old.frames.shape == recording.frames.shape \
                and np.array_equal(old.frames, recording.frames) and np.array_equal(old.timestamps, recording.timestamps):
            return target
        k += 1
        target = out / f"{name}-{k}{SUFFIX}"
    return target


def _expand(sources: list[str]) -> tuple[list[tuple[Path, Path]], list[str]]:
    from firmware_io.recordings.importers import find_sources

    found, errors = [], []
    for s in sources:
        p = Path(s)
        if p.is_dir() and not (p / "metadata.yaml").is_file():
            inside = list(find_sources(p))
            if not inside:
                errors.append(f"{p}: folder holds no .dsa, .bag or ROS 2 bag")
            found.extend((f, p) for f in inside)
        else:
            found.append((p, p.parent))
    return found, errors


def _subset(recording, pads: str):
    from firmware_io.recordings.recording import Recording

    cols = recording.layout.columns(pads)
    meta = {**recording.meta, "pads": list(recording.layout.pads(pads))}
    return Recording(recording.layout.subset(pads), recording.frames[:, cols], recording.timestamps, [], meta)


def _as_idle(recording, source: str, subject: str | None, src: Path):
    """The recording as one idle stretch of ``source`` (the way ``handover record`` stores its idle)."""
    from firmware_io.recordings.idle_stretches import idle_meta
    from firmware_io.recordings.recording import Recording

    n = recording.n_frames
    seconds = float(recording.timestamps[-1] - recording.timestamps[0]) if n > 1 else 0.0
    stretch = {"first": 0, "last": n - 1, "source": source, "index": 0, "seconds": round(seconds, 3),
               "extra": {"imported_from": str(src)}}
    meta = {**recording.meta, **idle_meta(n, [stretch] if n else [])}
    if subject:
        meta["subject"] = subject
    return Recording(recording.layout, recording.frames, recording.timestamps, [], meta)


def _summary(recording) -> str:
    n = recording.n_frames
    duration = float(recording.timestamps[-1] - recording.timestamps[0]) if n > 1 else 0.0
    interval = recording.sample_interval()
    rate = f"{1.0 / interval:.1f} Hz" if n > 1 and interval > 0 else "rate n/a"
    notes = []
    for key, label in (
        ("duplicate_frames_dropped", "duplicate frames dropped"),
        ("out_of_order_frames_dropped", "out-of-order frames dropped"),
        ("gaps_over_1s", "gaps > 1 s"),
    ):
        if recording.meta.get(key):
            notes.append(f"{recording.meta[key]} {label}")
    if recording.meta.get("dsa_dynamic_masks"):
        notes.append(f"dynamic mask: matrices {', '.join(recording.meta['dsa_dynamic_masks'])} not fully read")
    if recording.meta.get("idle_stretches"):
        notes.append(f"idle ({recording.meta['idle_stretches'][0]['source']})")
    extra = f" ({'; '.join(notes)})" if notes else ""
    return f"{n} frames, {duration:.1f} s, {rate}, {recording.layout.n_taxels} taxels{extra}"


def _bad_pad_name(pads: str) -> str | None:
    """A pad selection no sensor can satisfy (unknown name, empty), checked once before the batch.

    Indices are checked per file, since a sensor other than the SDH-2 may have more pads.
    """
    from firmware_io.layout import LayoutError, SensorLayout

    try:
        SensorLayout.sdh2().pads(pads)
    except LayoutError as exc:
        if "no matrix" not in str(exc):
            return str(exc)
    return None


def _report(src: Path, text: str) -> None:
    print(f"{PROG}: {text if str(src) in text else f'{src}: {text}'}", file=sys.stderr)


def main(args: argparse.Namespace) -> int:
    from firmware_io.recordings.importers import import_any
    from firmware_io.recordings.record_session import subject_problem
    from firmware_io.recordings.recording import SUFFIX

    if args.pads and (problem := _bad_pad_name(args.pads)):
        raise HandoverError(problem)
    if args.subject and not args.idle:
        raise HandoverError("--subject names whose idle an imported recording is; give --idle WHAT with it")
    if args.subject and (problem := subject_problem(args.subject)):  # a recorded subject's id, or one like it
        raise HandoverError(f"--subject: {problem}")
    out_folder(args.out)
    sources, errors = _expand(args.sources)
    for e in errors:
        print(f"{PROG}: {e}", file=sys.stderr)
    failed = len(errors)
    names = output_names(sources)
    for (src, _), name in zip(sources, names, strict=True):
        target = args.out / f"{name}{SUFFIX}"
        try:
            recording = import_any(src, topic=args.topic)
            if args.pads:
                recording = _subset(recording, args.pads)
            if args.idle:
                recording = _as_idle(recording, args.idle, args.subject, src)
            target = _free_target(args.out, name, recording)
            recording.save(target)
        except (HandoverError, OSError) as exc:
            _report(src, str(exc))
        except Exception as exc:  # one bad source must not stop the batch; say what broke
            _report(src, f"unexpected {type(exc).__name__}: {exc}")
        else:
            print(f"{src} -> {target}: {_summary(recording)}")
            continue
        failed += 1
    if failed:
        print(f"{PROG}: {failed} of {len(sources) + len(errors)} sources failed", file=sys.stderr)
        return 1
    return 0
