"""``handover review FOLDER``: label a daemon's captured events, one keystroke each.

Lists each captured event (time, decision, the robot's outcome, the label it proposes, the label
given) with the recorder's ASCII look at the pads, and takes one key: Enter confirms the label shown
(the one given before, else the outcome's proposal, else the decision),
1-4 or d gives a class, s skips, q quits. labels.json (beside the capture) is replaced atomically
after every answer, so Ctrl-C loses nothing. ``--accept-outcomes`` takes every proposal without asking
(the end-to-end bench). numpy only; ``--plot`` needs matplotlib.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TextIO

from firmware_io.recordings.recording import ACTIONS
from firmware_io.recordings.terminal_view import trial_view
from trainer.field_folder import CLASSES, CapturedEvent, FieldFolderError, read_events, read_labels, write_labels

__all__ = ["add_arguments", "main", "review"]

KEYS = {**{str(i): a for i, a in enumerate(ACTIONS, start=1)}, **{c[0]: c for c in CLASSES if c not in ACTIONS}}
"""One key per class: 1-4 the actions in ``ACTIONS`` order, d dormant."""
ENTER = ("\n", "\r")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", metavar="FOLDER", help="the daemon's [capture] folder")
    parser.add_argument("--list", action="store_true", help="list the captured events and exit")
    parser.add_argument("--accept-outcomes", action="store_true",
                        help="label every unlabelled event whose outcome proposes a label, without asking")
    parser.add_argument("--all", action="store_true", help="also ask about events already labelled")
    parser.add_argument("--plot", metavar="DIR", default=None,
                        help="also write each event asked about as DIR/EVENT.png (needs matplotlib)")


def event_line(index: int, ev: CapturedEvent, label: str | None) -> str:
    """One row of the listing: number, time, decision, outcome, proposed and given label."""
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(ev.time)) if ev.time is not None else "?"
    decided = "decided" if ev.reported else "unreported"
    return (f"{index:4d}  {when}  {decided:>10} {ev.decision:<8} outcome {ev.outcome or '-':<8} "
            f"proposes {ev.proposed or '-':<8} label {label or '-'}")


def default_label(ev: CapturedEvent, given: str | None) -> tuple[str, str]:
    """What Enter confirms, and why: the label given before, else the outcome's proposal, else the decision."""
    for label, why in ((given, "given"), (ev.proposed, "proposed"), (ev.decision, "decided")):
        if label in CLASSES:
            return label, why
    return "", ""


def _answer(default: tuple[str, str], read_key: Callable[[], str], out: TextIO) -> str | None:
    """A class, "s" (skip) or None (quit: q, or the end of input)."""
    keys = "  ".join(f"{k} {c}" for k, c in KEYS.items())
    enter = f"Enter: {default[0]} ({default[1]})  " if default[0] else ""
    while True:
        out.write(f"  {enter}{keys}  s skip  q quit > ")
        out.flush()
        key = read_key()
        out.write("\n" if key in ENTER or not key else f"{key}\n")
        if not key or key == "q":
            return None
        if key in ENTER and default[0]:
            return default[0]
        if key == "s" or key in KEYS:
            return KEYS.get(key, key)
        out.write("  no label shown: press a class key, s or q\n" if key in ENTER else
                  f"  key {key!r}: press Enter, {', '.join(KEYS)}, s or q\n")


def review(folder: Path, read_key: Callable[[], str], out: TextIO, say: Callable[[str], None],
           ask_all: bool = False, plot: Path | None = None) -> dict[str, str]:
    """Ask about each event (those without a label unless ``ask_all``); labels.json is written after
    every answer. Returns the labels."""
    labels = read_labels(folder)  # junk raises here, before anything could overwrite it
    events = read_events(folder, say)
    asked = [(i, ev) for i, ev in enumerate(events, start=1) if ask_all or ev.stem not in labels]
    out.write(f"{len(asked)} of {len(events)} captured events to review in {folder}\n")
    for i, ev in asked:
        out.write(f"\n{event_line(i, ev, labels.get(ev.stem))}\n")
        trial = ev.recording.trials[0]
        out.write(trial_view(ev.recording.trial_frames(trial)[0], ev.recording.layout,
                             ev.report_frame - trial.first if ev.report_frame >= 0 else -1) + "\n")
        if plot is not None:
            from trainer.commands.plot_cli import plot_trial

            try:
                out.write(f"  {plot_trial(ev.recording, 0, plot / f'{ev.stem}.png')}\n")
            except OSError as exc:  # a file, /proc, another user's folder: one line, not a traceback
                raise FieldFolderError(f"--plot {plot}: cannot write there ({exc.strerror or exc}); give a "
                                       "folder you can write") from None
        answer = _answer(default_label(ev, labels.get(ev.stem)), read_key, out)
        if answer is None:
            break
        if answer != "s":
            labels[ev.stem] = answer
            write_labels(folder, labels)
    return labels


def accept_outcomes(folder: Path, out: TextIO, say: Callable[[str], None]) -> dict[str, str]:
    """Every unlabelled event whose outcome proposes a label gets it; labels.json written once."""
    labels = read_labels(folder)
    events = read_events(folder, say)
    new = {ev.stem: ev.proposed for ev in events if ev.stem not in labels and ev.proposed}
    if new:
        write_labels(folder, labels | new)
    left = sum(1 for ev in events if ev.stem not in labels and ev.stem not in new)
    out.write(f"{len(new)} events labelled from their outcomes, {len(labels)} labelled before, {left} without a "
              f"proposal (review them: handover review {folder})\n")
    return labels | new


@contextlib.contextmanager
def keystrokes(stream: TextIO) -> Iterator[Callable[[], str]]:
    """One character per call: a terminal in cbreak mode (no Enter needed; Ctrl-C still interrupts),
    else the stream as it comes. The terminal's mode is restored on every exit."""
    if not stream.isatty():
        yield lambda: stream.read(1)
        return
    import termios
    import tty

    fd = stream.fileno()
    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)
        yield lambda: stream.read(1)
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def main(args: argparse.Namespace) -> int:
    folder = Path(args.folder)

    def say(line: str) -> None:
        print(f"handover review: {line}", file=sys.stderr)

    if args.list:
        labels = read_labels(folder)
        for i, ev in enumerate(read_events(folder, say), start=1):
            print(event_line(i, ev, labels.get(ev.stem)))
        return 0
    if args.accept_outcomes:
        accept_outcomes(folder, sys.stdout, say)
        return 0
    with keystrokes(sys.stdin) as read_key:
        labels = review(folder, read_key, sys.stdout, say, ask_all=args.all,
                        plot=Path(args.plot) if args.plot else None)
    print(f"{len(labels)} events labelled in {folder}")
    return 0
