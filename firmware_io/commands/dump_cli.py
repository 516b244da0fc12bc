"""``handover dump URL``: open a controller, print its layout and then frames as they arrive.

The first thing to run when the hand is plugged in: it shows whether the link works, what
the controller reports, the frame rate, per-pad sums (press a pad and watch its column) and
every parser error.

The preview (no ``--frames``, no ``--seconds``) starts at the first frame with contact: a hand
nobody touches sends all-zero frames, and fifty rows of zeros show nothing. The skipped frames
are counted, said so in one line, and a line every few seconds tells that the link is alive
while nothing touches the pads. ``--all-frames`` shows every frame from the first.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

BURST_NOTE = "n/a (as fast as possible: the frames arrived together)"
PREVIEW_FRAMES = 50
IDLE_NOTE_EVERY_S = 3.0
"""While the preview skips frames without contact, say so this often (the link is alive)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("url", help="device URL: serial:///dev/ttyUSB0, tcp://192.168.1.42:13000, usb://VID:PID, "
                        "hid://VID:PID, sim://, replay://FILE, or a /dev path")
    parser.add_argument("--frames", type=int, default=None,
                        help=f"stop after N frames (default: a preview of {PREVIEW_FRAMES} frames from the first "
                        "contact, unless --seconds)")
    parser.add_argument("--all-frames", action="store_true",
                        help="the preview shows frames without contact too (it starts at the first contact)")
    parser.add_argument("--seconds", type=float, default=None, help="stop after S seconds of streaming")
    parser.add_argument("--json", action="store_true", help="one JSON object a line: layout, frames, summary")
    parser.add_argument("--raw", action="store_true", help="ask for raw frames instead of RLE")


def _fail(message: str) -> int:
    print(f"handover dump: {message}", file=sys.stderr)
    return 1


def main(args: argparse.Namespace) -> int:
    import numpy as np

    from firmware_io.client import DSAClient
    from firmware_io.transports import TransportError
    from firmware_io.wire.errors import DSAError

    if args.frames is not None and args.frames < 1:
        return _fail("--frames must be at least 1")
    if args.seconds is not None and args.seconds <= 0:
        return _fail("--seconds must be positive")
    preview = args.frames is None and args.seconds is None
    max_frames = args.frames if args.frames is not None else (None if args.seconds else PREVIEW_FRAMES)
    emit = _json_line if args.json else None
    idle = IdleSkip(enabled=preview and not args.all_frames, emit=emit)

    client = DSAClient(args.url, rle=not args.raw, auto_reconnect=False)
    count, first_rx, last_rx, first_ts, last_ts = 0, None, None, None, None
    cut_by_end = 0  # reads that ended empty because --seconds ran out: the end, not a timeout
    try:
        layout = client.open()
        ctrl = client.controller
        header = {
            "type": "layout",
            "url": args.url,
            "firmware": ctrl.firmware if ctrl else None,
            "controller_serial": ctrl.serial_no if ctrl else None,
            "n_taxels": layout.n_taxels,
            "matrices": [{"index": m.index, "cells_x": m.cells_x, "cells_y": m.cells_y} for m in layout.matrices],
        }
        if emit:
            emit(header)
        else:
            print(f"{args.url}: controller firmware {header['firmware']}, serial {header['controller_serial']}")
            sizes = ", ".join(f"{m.index}: {m.cells_x}x{m.cells_y}" for m in layout.matrices)
            print(f"{layout.n_matrices} pads, {layout.n_taxels} taxels ({sizes})")
            print("frame   device_ms   dt_ms  " + "  ".join(f"pad{m.index:>4}" for m in layout.matrices) + "    max")
        slices = [layout.matrix_slice(m.index) for m in layout.matrices]
        client.start()
        end = None if args.seconds is None else time.monotonic() + args.seconds  # streaming time, not open time
        while (max_frames is None or count < max_frames) and (end is None or time.monotonic() < end):
            wait = 1.0 if end is None else max(0.0, min(1.0, end - time.monotonic()))
            frame = client.read_frame(timeout=wait)
            if frame is None:
                if end is None:
                    return _fail(f"no frame for 1 s (errors so far: {_errors(client.stats)})")
                if time.monotonic() >= end:
                    cut_by_end += 1
                continue
            if idle.skip(frame):
                continue
            sums = [int(np.sum(frame.values[s], dtype=np.int64)) for s in slices]
            dt = None if last_ts is None else frame.timestamp_ms - last_ts
            first_rx = frame.received if first_rx is None else first_rx
            first_ts = frame.timestamp_ms if first_ts is None else first_ts
            last_rx, last_ts = frame.received, frame.timestamp_ms
            count += 1
            if emit:
                emit({"type": "frame", "number": frame.number, "timestamp_ms": frame.timestamp_ms,
                      "pad_sums": sums, "max": int(frame.values.max(initial=0))})
            else:
                dt_text = "" if dt is None else str(dt)
                print(f"{frame.number:>5} {frame.timestamp_ms:>11} {dt_text:>7}  "
                      + "  ".join(f"{v:>7}" for v in sums) + f" {int(frame.values.max(initial=0)):>6}")
    except (TransportError, DSAError) as exc:
        return _fail(str(exc))
    except KeyboardInterrupt:
        pass
    finally:
        stats = client.stats
        stats["timeouts"] = max(0, stats.get("timeouts", 0) - cut_by_end)
        client.close()
    rate = (count - 1) / (last_rx - first_rx) if count > 1 and last_rx > first_rx else None
    # Frames parsed from one read share one receive time: a source sending as fast as possible.
    burst = count > 1 and rate is None
    device_rate = (count - 1) * 1000.0 / (last_ts - first_ts) if count > 1 and last_ts > first_ts else None
    summary = {"type": "summary", "frames": count, "idle_frames_skipped": idle.skipped, "rate_hz": rate, "device_rate_hz": device_rate, "stats": stats}
    if burst:
        summary["rate_note"] = BURST_NOTE
    if emit:
        emit(summary)
    else:
        r = BURST_NOTE if burst else "n/a" if rate is None else f"{rate:.1f} Hz"
        d = "n/a" if device_rate is None else f"{device_rate:.1f} Hz"
        skipped = f" (after {idle.skipped} frames without contact)" if idle.skipped else ""
        print(f"{count} frames{skipped}, received at {r} (device clock {d}); errors: {_errors(stats)}")
    return 0


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
    keys = ("crc_errors", "bad_headers", "packets_dropped", "bytes_dropped", "decode_errors", "boot_queries",
            "reconnects", "timeouts")
    return ", ".join(f"{k} {stats.get(k, 0)}" for k in keys)


def _json_line(obj: dict) -> None:
    print(json.dumps(obj), flush=True)
