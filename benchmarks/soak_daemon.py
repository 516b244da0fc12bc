"""``python -m benchmarks.soak_daemon --frame-log FILE run --config CONFIG``: ``handover run``
(the real CLI path, signals, sd_notify, sinks) with one observation added for the soak benchmark:
the device timestamp and arrival time (CLOCK_MONOTONIC, the same clock in every process on Linux)
of every frame the daemon handles are appended to FILE, 16 bytes a frame. Nothing else changes.
"""

from __future__ import annotations

import struct
import sys
import time

RECORD = struct.Struct("<qd")
FLUSH_S = 0.5


def main(argv: list[str]) -> int:
    if len(argv) < 3 or argv[0] != "--frame-log":
        print("usage: python -m benchmarks.soak_daemon --frame-log FILE run --config CONFIG", file=sys.stderr)
        return 2
    log_path, rest = argv[1], argv[2:]
    import runtime.daemon as daemon_module
    from runtime import cli

    out = open(log_path, "ab", buffering=1 << 16)  # noqa: SIM115 - closed at exit below
    base = daemon_module.Daemon
    state = {"flushed": time.monotonic()}

    class ObservedDaemon(base):
        def handle_frame(self, frame) -> None:
            now = time.monotonic()
            out.write(RECORD.pack(int(frame.timestamp_ms), now))
            if now - state["flushed"] >= FLUSH_S:
                out.flush()
                state["flushed"] = now
            super().handle_frame(frame)

    daemon_module.Daemon = ObservedDaemon
    try:
        return cli.main(rest)
    finally:
        out.close()


def read_frame_log(path) -> tuple[list[int], list[float]]:
    """Device stamps (ms) and arrival times of every frame the daemon handled."""
    return FrameLogTail(path).read()


class FrameLogTail:
    """The frame log read as it grows (the soak's schedule follows the daemon while it runs): each
    ``read`` returns the whole records appended since the last one."""

    def __init__(self, path) -> None:
        self.path, self.offset = path, 0

    def read(self) -> tuple[list[int], list[float]]:
        """Device stamps (ms) and arrival times of the frames logged since the last read."""
        try:
            with open(self.path, "rb") as fh:
                fh.seek(self.offset)
                data = fh.read()
        except FileNotFoundError:
            return [], []
        n = len(data) // RECORD.size
        self.offset += n * RECORD.size
        stamps, times = [], []
        for stamp, t in RECORD.iter_unpack(data[: n * RECORD.size]):
            stamps.append(stamp)
            times.append(t)
        return stamps, times


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
