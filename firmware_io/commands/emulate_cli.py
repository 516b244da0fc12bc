"""``handover emulate``: serve an emulated DSACON32m on loopback TCP or a pseudo-terminal.

Frames come from the simulated hand's scripted session (synthetic data; by default the demo's
session, whose simulated subjects no demo model trains on) or any recording (.hrec, .dsa, .bag). Point any client at the printed URL, e.g. ``handover dump tcp://127.0.0.1:13000``.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time

from firmware_io.commands.options import add_lab, add_seed, int_in, positive_float
from firmware_io.errors import HandoverError

__all__ = ["add_arguments", "main"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--listen", metavar="URL", help="tcp://127.0.0.1:PORT (loopback only; port 0 picks one)")
    where.add_argument("--pty", action="store_true", help="serve on a pseudo-terminal and print its path")
    from firmware_io.sim.session import DEMO_SESSION_SEED, HELD_OUT_SEED_OFFSET
    from firmware_io.transports.base import MAX_EVENTS

    parser.add_argument("--source", default="sim", help="'sim' (simulated hand, default) or a recording file")
    parser.add_argument("--events", type=int_in(1, MAX_EVENTS), default=40,
                        help="scripted events of the simulated session (default 40)")
    add_seed(parser, DEMO_SESSION_SEED,
             help=f"seed of the simulated session and of fault injection (default {DEMO_SESSION_SEED}: "
             "the demo's scripted session, by simulated subjects no demo model trains on; a model trained "
             f"on simulator seed s meets new subjects at s + {HELD_OUT_SEED_OFFSET})")
    add_lab(parser, "the simulated session")
    parser.add_argument("--speed", default="1.0", help="playback speed: a factor (1.0 = recorded timing) or 'max'")
    parser.add_argument(
        "--fault",
        default="",
        help="faults to inject, e.g. crc=0.01,garbage=0.01,drop=0.01,stall=0.005:0.5,disconnect=300,boot",
    )
    parser.add_argument("--old-firmware", action="store_true", help="behave like firmware <= R288 (single frame pushes)")
    parser.add_argument("--no-loop", action="store_true", help="stop sending at the end of the recording")
    parser.add_argument("--duration", type=positive_float, default=None,
                        help="exit after this many seconds (default: Ctrl-C)")
    parser.add_argument("--clock-start", type=int_in(0, 2**32 - 1), default=0, metavar="MS",
                        help="the device clock's value at power-on, in ms (0..4294967295; it wraps there)")
    parser.add_argument("--boot-seconds", type=float, default=None, metavar="S",
                        help="how long a power cycle (--fault disconnect=N, or a TCP host leaving) keeps the controller "
                             "silent; ESC[5n comes from 1 s before it ends (default 8, as the real one)")
    parser.add_argument("--script-out", metavar="FILE",
                        help="write the session's scripted events (onset frame, action, subject, frame span) and "
                             "its device times, for handover score EVENTS.jsonl FILE")


def _write_script(args: argparse.Namespace, recording, emulator, ended: bool = False) -> None:
    """The session's script; until a host asks for frames its device times are not known yet
    (``started: false``), and the file is written again when they are, and once more when a
    ``--no-loop`` session has been sent whole (``ended``: unanswered events were missed, not unplayed)."""
    from firmware_io.emulator.script_file import write_script

    start = emulator.session_clock_ms
    try:
        write_script(args.script_out, recording, args.clock_start if start is None else start, loop=not args.no_loop,
                     source=str(args.source), started=start is not None, ended=ended)
    except OSError as exc:
        raise HandoverError(f"--script-out {args.script_out}: cannot write ({exc.strerror or exc})") from None


def _interrupt(*_: object) -> None:
    raise KeyboardInterrupt


def _server(args: argparse.Namespace, emulator):
    """The pty or TCP server ``args`` ask for."""
    from firmware_io.emulator.server import PtyEmulatorServer, TcpEmulatorServer
    from firmware_io.transports.base import ParsedURL

    if args.pty:
        return PtyEmulatorServer(emulator)
    parsed = ParsedURL(args.listen)
    if parsed.scheme != "tcp" or not parsed.netloc or parsed.path not in ("", "/") or parsed.options:
        raise HandoverError(f"--listen {args.listen!r}: use tcp://127.0.0.1:PORT (or --pty for a pseudo-terminal "
                            "to open as serial://)")
    host, _, port = parsed.netloc.rpartition(":")
    if not host or not port.isdigit() or int(port) > 65535:
        raise HandoverError(f"--listen {args.listen!r}: use tcp://127.0.0.1:PORT with a port 0..65535 (0 picks one)")
    return TcpEmulatorServer(emulator, host=host, port=int(port))


def main(args: argparse.Namespace) -> int:
    from firmware_io.commands.playback import playback_options
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.frame_source import load_source

    try:
        speed, faults = playback_options(args.speed, args.fault)
    except ValueError as exc:
        raise HandoverError(str(exc)) from None
    boot = {}
    if args.boot_seconds is not None:
        if not 0 <= args.boot_seconds <= 600:  # also NaN
            raise HandoverError(f"--boot-seconds must be within 0..600, got {args.boot_seconds}")
        boot = {"boot_s": args.boot_seconds, "boot_query_s": max(0.0, args.boot_seconds - 1.0)}
    recording = load_source(args.source, seed=args.seed, events=args.events, lab=args.lab)
    emulator = DeviceEmulator(
        recording, speed=speed, loop=not args.no_loop, old_firmware=args.old_firmware, faults=faults, seed=args.seed,
        start_ms=args.clock_start, session_starts="first_acquisition", **boot,
    )
    if args.script_out:
        _write_script(args, recording, emulator)  # again, with the device time the session starts at, once asked
        if not recording.trials:
            print(f"handover emulate: warning: {args.source} has no scripted events; {args.script_out} holds none",
                  file=sys.stderr, flush=True)
    server = _server(args, emulator)

    signal.signal(signal.SIGTERM, _interrupt)  # a service manager's stop ends like Ctrl-C: summary, clean close
    synthetic = " (synthetic)" if recording.meta.get("synthetic", args.source == "sim") else ""
    what = "simulated hand" if args.source == "sim" else str(args.source)
    rate = 1.0 / recording.sample_interval() if recording.n_frames > 1 else float("nan")
    print(
        f"emulated DSACON32m: {what}{synthetic}, {recording.n_frames} frames, {recording.layout.n_matrices} pads, "
        f"{recording.layout.n_taxels} taxels, {rate:.1f} Hz, speed {args.speed}"
        + (f", faults {args.fault}" if faults.any else "")
        + (f"; script in {args.script_out}" if args.script_out else ""),
        flush=True,
    )
    server.start()
    try:
        _serve(args, server, emulator, recording)
    finally:
        server.stop()
    s = emulator.stats
    print(
        f"served {s.connections} connection(s), {s.commands} commands, {s.frames_sent} frames; "
        f"faults: crc {s.crc_corrupted}, garbage {s.garbage_inserted}, truncated {s.packets_truncated}, "
        f"stalls {s.stalls}, disconnects {s.disconnects}",
        flush=True,
    )
    return 0


def _serve(args: argparse.Namespace, server, emulator, recording) -> None:
    """Serve until ``--duration`` or Ctrl-C, saying when the session starts and ends."""
    end = None if args.duration is None else time.monotonic() + args.duration
    script_due = bool(args.script_out)
    end_due = bool(args.no_loop)
    try:  # a SIGTERM right after the first line is a clean stop too
        if args.pty:
            print(f"pty: {server.path}  (open serial://{server.path})", flush=True)
        else:
            print(f"listening: {server.url}", flush=True)
        while end is None or time.monotonic() < end:
            time.sleep(0.2 if end is None else max(0.0, min(0.2, end - time.monotonic())))
            if server.error is not None:
                raise HandoverError(f"server stopped: {server.error}")
            if script_due and emulator.session_clock_ms is not None:
                script_due = False
                _write_script(args, recording, emulator)
                print(f"session started at device time {emulator.session_clock_ms} ms; script: {args.script_out}",
                      flush=True)
            if end_due and emulator.finished:  # the host now only sees a stall: say the session is over
                end_due = False
                if args.script_out and not script_due:
                    _write_script(args, recording, emulator, ended=True)
                score = f"; then handover score EVENTS.jsonl {args.script_out}" if args.script_out else ""
                print(f"session over: all {recording.n_frames} frames sent (--no-loop); stop the daemon{score}; "
                      "Ctrl-C ends the emulator", flush=True)
    except KeyboardInterrupt:
        pass
