"""``handover dump URL``: open a controller, print its layout and then frames as they arrive.

The first thing to run when the hand is plugged in. The preview starts at the first frame with contact
(``--all-frames``: from the first frame), since an untouched hand sends only zeros. A pause in a count
of frames is waited out up to ``--timeout`` (the client restarts push mode after 2 s of silence).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass

from firmware_io.commands.options import add_json, positive_float, positive_int
from firmware_io.errors import DeviceFailure, HandoverError
from firmware_io.transports.tcp import URL_FORM
from firmware_io.wire.replies import serial_text

__all__ = ["add_arguments", "main"]

COMMAND = "dump"

BURST_NOTE = "n/a (as fast as possible: the frames arrived together)"
PREVIEW_FRAMES = 50
IDLE_NOTE_EVERY_S = 3.0
"""While the preview skips frames without contact, say so this often (the link is alive)."""
SILENCE_TIMEOUT_S = 10.0
"""How long a count of frames waits through a pause by default: longer than the reader's own push
restart after 2 s of silence and a controller's 8 s power cycle, short enough for a dead link."""
WAIT_NOTE_AFTER_S = 1.0
"""A pause this long is said on stderr (once per pause), so a waiting dump never looks hung."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("url", help=f"device URL: serial:///dev/ttyUSB0, {URL_FORM}, usb://VID:PID, "
                        "hid://VID:PID, sim://, replay://FILE, or a /dev path")
    parser.add_argument("--frames", type=positive_int, default=None,
                        help=f"stop after N frames (default: a preview of {PREVIEW_FRAMES} frames from the first "
                        "contact, unless --seconds)")
    parser.add_argument("--all-frames", action="store_true",
                        help="the preview shows frames without contact too (it starts at the first contact)")
    parser.add_argument("--seconds", type=positive_float, default=None, help="stop after S seconds of streaming")
    parser.add_argument("--timeout", type=positive_float, default=SILENCE_TIMEOUT_S, metavar="S",
                        help="without --seconds: wait this long for a frame when the device pauses (a controller "
                        "between streams, a loose cable), then stop with exit 1 (default: %(default)g; "
                        "--seconds always waits to its end)")
    add_json(parser, "layout, frames and summary, one object a line,")
    parser.add_argument("--raw", action="store_true", help="ask for raw frames instead of RLE")


def main(args: argparse.Namespace) -> int:
    from firmware_io.client import DSAClient
    from firmware_io.transports import TransportError, validate_url
    from firmware_io.wire.errors import DSAError

    try:
        validate_url(args.url)  # a URL that can never open is the user's to fix (exit 2), not the device's
    except TransportError as exc:
        raise HandoverError(str(exc)) from None
    preview = args.frames is None and args.seconds is None
    problem = None
    emit = _json_line if args.json else None
    idle = IdleSkip(enabled=preview and not args.all_frames, emit=emit)
    tally = Tally()
    client = DSAClient(args.url, rle=not args.raw, auto_reconnect=False, on_wait=_stderr)  # a boot: 8 s silent
    try:
        layout = client.open()
        _show_layout(args.url, client, layout, emit)
        client.start()
        problem = _stream(args, client, layout, idle, tally, emit)
    except (TransportError, DSAError) as exc:
        if not tally.count:
            raise DeviceFailure(str(exc)) from exc
        problem = str(exc)  # a device that dies mid-dump: the frames shown are still summed up
    except KeyboardInterrupt:
        pass
    finally:
        stats = client.stats
        stats["timeouts"] = max(0, stats.get("timeouts", 0) - tally.cut_by_end)
        client.close()
    _show_summary(tally, idle.skipped, stats, emit)
    if problem:
        raise DeviceFailure(problem)
    return 0


@dataclass
class Tally:
    """Frames shown so far, the receive and device times of the first and last, and the reads that ended
    empty because --seconds ran out (the end, not a timeout)."""

    count: int = 0
    first_rx: float | None = None
    last_rx: float | None = None
    first_ts: int | None = None
    last_ts: int | None = None
    cut_by_end: int = 0

    def add(self, frame) -> int | None:
        """Count a frame; the device milliseconds since the previous one (None for the first)."""
        dt = None if self.last_ts is None else frame.timestamp_ms - self.last_ts
        self.first_rx = frame.received if self.first_rx is None else self.first_rx
        self.first_ts = frame.timestamp_ms if self.first_ts is None else self.first_ts
        self.last_rx, self.last_ts = frame.received, frame.timestamp_ms
        self.count += 1
        return dt


def _show_layout(url: str, client, layout, emit) -> None:
    ctrl = client.controller
    header = {
        "type": "layout",
        "url": url,
        "firmware": ctrl.firmware if ctrl else None,
        "controller_serial": ctrl.serial_no if ctrl else None,
        "n_taxels": layout.n_taxels,
        "matrices": [{"index": m.index, "cells_x": m.cells_x, "cells_y": m.cells_y} for m in layout.matrices],
    }
    if emit:
        emit(header)
        return
    serial = serial_text(ctrl.serial_no) if ctrl else None
    print(f"{url}: controller firmware {header['firmware']}, serial {serial}")
    sizes = ", ".join(f"{m.index}: {m.cells_x}x{m.cells_y}" for m in layout.matrices)
    print(f"{layout.n_matrices} pads, {layout.n_taxels} taxels ({sizes})")
    print("frame   device_ms   dt_ms  " + "  ".join(f"pad{m.index:>4}" for m in layout.matrices) + "    max")


def _stream(args: argparse.Namespace, client, layout, idle: IdleSkip, tally: Tally, emit) -> str | None:
    """Show frames until --frames or --seconds (or the preview's count); what went wrong, or None."""
    import numpy as np

    preview = args.frames is None and args.seconds is None
    max_frames = args.frames if args.frames is not None else (PREVIEW_FRAMES if preview else None)
    slices = [layout.matrix_slice(m.index) for m in layout.matrices]
    end = None if args.seconds is None else time.monotonic() + args.seconds  # streaming time, not open time
    heard = time.monotonic()
    said_waiting = False
    while (max_frames is None or tally.count < max_frames) and (end is None or time.monotonic() < end):
        wait = min(1.0, max(0.01, heard + args.timeout - time.monotonic())) if end is None else \
            max(0.0, min(1.0, end - time.monotonic()))
        frame = client.read_frame(timeout=wait)
        if frame is None:
            if end is None:
                silent = time.monotonic() - heard
                if silent >= args.timeout:
                    return (f"no frame for {args.timeout:g} s, stopped (errors so far: {_errors(client.stats)}); "
                            "check the link, or wait longer with --timeout S")
                if not said_waiting and silent >= WAIT_NOTE_AFTER_S:
                    said_waiting = True
                    _stderr(f"no frame for {WAIT_NOTE_AFTER_S:g} s (the device paused, or the link is lost); waiting "
                            f"up to {args.timeout:g} s for the next (--timeout S; Ctrl-C stops)")
            elif time.monotonic() >= end:
                tally.cut_by_end += 1
            continue
        if said_waiting:
            said_waiting = False
            _stderr(f"frames again after {time.monotonic() - heard:.1f} s without one")
        heard = time.monotonic()
        if idle.skip(frame):
            continue
        sums = [int(np.sum(frame.values[s], dtype=np.int64)) for s in slices]
        dt = tally.add(frame)
        peak = int(frame.values.max(initial=0))
        if emit:
            emit({"type": "frame", "number": frame.number, "timestamp_ms": frame.timestamp_ms,
                  "pad_sums": sums, "max": peak})
        else:
            dt_text = "" if dt is None else str(dt)
            print(f"{frame.number:>5} {frame.timestamp_ms:>11} {dt_text:>7}  "
                  + "  ".join(f"{v:>7}" for v in sums) + f" {peak:>6}")
    return None


def _show_summary(t: Tally, skipped: int, stats: dict, emit) -> None:
    rate = (t.count - 1) / (t.last_rx - t.first_rx) if t.count > 1 and t.last_rx > t.first_rx else None
    # Frames parsed from one read share one receive time: a source sending as fast as possible.
    burst = t.count > 1 and rate is None
    device_rate = (t.count - 1) * 1000.0 / (t.last_ts - t.first_ts) if t.count > 1 and t.last_ts > t.first_ts else None
    summary = {"type": "summary", "frames": t.count, "idle_frames_skipped": skipped, "rate_hz": rate,
               "device_rate_hz": device_rate, "stats": stats}
    if burst:
        summary["rate_note"] = BURST_NOTE
    if emit:
        emit(summary)
        return
    r = BURST_NOTE if burst else "n/a" if rate is None else f"{rate:.1f} Hz"
    d = "n/a" if device_rate is None else f"{device_rate:.1f} Hz"
    skipped_text = f" (after {skipped} frames without contact)" if skipped else ""
    print(f"{t.count} frames{skipped_text}, received at {r} (device clock {d}); errors: {_errors(stats)}")


class IdleSkip:
    """The preview's skip of leading frames without contact, and its notes."""

    def __init__(self, enabled: bool, emit) -> None:
        self.active = enabled
        self.emit = emit
        self.skipped = 0
        self._last_note = time.monotonic()

    def skip(self, frame) -> bool:
        """True while the frame is one of the leading frames without contact (all taxels 0)."""
        if not self.active:
            return False
        if int(frame.values.max(initial=0)) == 0:
            self.skipped += 1
            if time.monotonic() - self._last_note >= IDLE_NOTE_EVERY_S:
                self._last_note = time.monotonic()
                self._note(f"... {self.skipped} frames so far, none with contact: the link works; press a pad "
                           "(--all-frames shows every frame)")
            return True
        self.active = False
        if self.skipped:
            self._note(f"(skipped {self.skipped} frames without contact; first contact at frame {frame.number}; "
                       "--all-frames shows every frame)")
        return False

    def _note(self, text: str) -> None:
        if self.emit:
            self.emit({"type": "note", "text": text})
        else:
            print(text, flush=True)


def _errors(stats: dict) -> str:
    """The byte stream's errors, then the link's counts apart: a controller that boots asks for the terminal
    and leaves the open's first requests unanswered (timeouts) without anything being wrong."""
    errors = ("crc_errors", "bad_headers", "packets_dropped", "bytes_dropped", "decode_errors")
    link = ("boot_queries", "reconnects", "timeouts")
    return "; link: ".join(", ".join(f"{k} {stats.get(k, 0)}" for k in keys) for keys in (errors, link))


def _stderr(text: str) -> None:
    print(f"handover {COMMAND}: {text}", file=sys.stderr, flush=True)


def _json_line(obj: dict) -> None:
    print(json.dumps(obj), flush=True)
