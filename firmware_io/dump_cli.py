"""``handover dump URL``: open a controller, print its layout and then frames as they arrive.

The first thing to run when the hand is plugged in: it shows whether the link works, what
the controller reports, the frame rate, per-pad sums (press a pad and watch its column) and
every parser error.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

BURST_NOTE = "n/a (as fast as possible: the frames arrived together)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("url", help="device URL: serial:///dev/ttyUSB0, tcp://192.168.1.42:13000, usb://VID:PID, "
                        "hid://VID:PID, sim://, replay://FILE, or a /dev path")
    parser.add_argument("--frames", type=int, default=None, help="stop after N frames (default 50 unless --seconds)")
    parser.add_argument("--seconds", type=float, default=None, help="stop after S seconds of streaming")
    parser.add_argument("--json", action="store_true", help="one JSON object a line: layout, frames, summary")
    parser.add_argument("--raw", action="store_true", help="ask for raw frames instead of RLE")


def _fail(message: str) -> int:
    print(f"handover dump: {message}", file=sys.stderr)
    return 1


def main(args: argparse.Namespace) -> int:
    import numpy as np

    from firmware_io.client import DSAClient
    from firmware_io.protocol import DSAError
    from firmware_io.transports import TransportError

    if args.frames is not None and args.frames < 1:
        return _fail("--frames must be at least 1")
    if args.seconds is not None and args.seconds <= 0:
        return _fail("--seconds must be positive")
    max_frames = args.frames if args.frames is not None else (None if args.seconds else 50)
    emit = _json_line if args.json else None

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
    summary = {"type": "summary", "frames": count, "rate_hz": rate, "device_rate_hz": device_rate, "stats": stats}
    if burst:
        summary["rate_note"] = BURST_NOTE
    if emit:
        emit(summary)
    else:
        r = BURST_NOTE if burst else "n/a" if rate is None else f"{rate:.1f} Hz"
        d = "n/a" if device_rate is None else f"{device_rate:.1f} Hz"
        print(f"{count} frames, received at {r} (device clock {d}); errors: {_errors(stats)}")
    return 0


def _errors(stats: dict) -> str:
    keys = ("crc_errors", "bad_headers", "packets_dropped", "bytes_dropped", "decode_errors", "boot_queries",
            "reconnects", "timeouts")
    return ", ".join(f"{k} {stats.get(k, 0)}" for k in keys)


def _json_line(obj: dict) -> None:
    print(json.dumps(obj), flush=True)
