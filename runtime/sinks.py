"""Where events go: JSON lines on stdout (journald), UDP datagrams, Unix datagram sockets, ROS 2.

An event is serialised once and handed to every sink. A sink that fails (no listener, full
buffer, closed pipe) is logged (rate-limited) and counted, and never stops the daemon.
The line format is the event protocol (docs/EVENTS.md, docs/events.schema.json).
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import os
import socket
import sys
import threading
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from json.encoder import encode_basestring_ascii as _ascii  # the encoder's own string writer (ensure_ascii)
from math import isfinite
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Protocol

from firmware_io.errors import HandoverError
from runtime.config import parse_host_port
from runtime.name_resolver import ResolvedTarget

__all__ = [
    "PROTOCOL_VERSION", "DaemonSide", "Event", "ModelAnnouncement", "Sink", "SinkSet", "StdoutSink", "UdpSink",
    "UnixDatagramSink", "claim_stdout_for_events", "log"
]

if TYPE_CHECKING:
    from runtime.config import Ros2Config, SinksConfig

log = logging.getLogger("handover.sinks")

_compact = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode
"""One encoder built once (``json.dumps`` with options builds a new one per call)."""

PROTOCOL_VERSION = 1
"""The event protocol's version (docs/EVENTS.md): raised only when a field changes meaning or
goes away; new fields and new line types keep it (listeners ignore what they do not know)."""


@dataclass
class Event:
    """One decision reported to the outside world (a ``"type": "decision"`` line)."""

    time: float
    """Wall-clock time (Unix seconds) when the decision was made."""
    cls: str
    scores: dict[str, float]
    latency_us: float
    """From the arrival of the window's last frame (Frame.received) to the decision."""
    model_id: str
    frame_first: int
    frame_last: int
    device_time_ms: int = 0
    missed_deadline: bool = False
    instance: str = ""
    """Which daemon decided (runtime.instance_name); the SinkSet stamps it."""

    def to_json(self) -> str:
        # The fields spelled out (not dataclasses.asdict, which deep-copies): this runs on the hot path.
        scores = {k: round(float(v), 6) for k, v in self.scores.items()}
        latency = round(float(self.latency_us), 1)
        line = self._plain_line(scores, latency)
        if line is not None:
            return line
        d = {"type": "decision", "protocol": PROTOCOL_VERSION, "instance": self.instance, "class": self.cls, "time": self.time,
             "scores": scores, "latency_us": latency, "model_id": self.model_id,
             "frame_first": self.frame_first, "frame_last": self.frame_last,
             "device_time_ms": self.device_time_ms, "missed_deadline": self.missed_deadline}
        # allow_nan=False: NaN/Infinity are not JSON; such an event raises ValueError here, the
        # one place events are serialised, and never reaches a listener.
        return _compact(d)

    def _plain_line(self, scores: dict, latency: float) -> str | None:
        """The line ``_compact`` writes for the dict above, character for character, when every value
        is a plain str, int, bool or finite float (a decision's case); else None (the encoder decides,
        and refuses). Why: on the cold caches after a model run the encoder took twice as long
        (results/latency.md, "JSON line encoded")."""
        parts = []
        for key, value in scores.items():
            if type(key) is not str or not isfinite(value):
                return None
            parts.append(f"{_ascii(key)}:{value!r}")
        if not (type(self.cls) is str and type(self.model_id) is str and type(self.instance) is str
                and type(self.time) is float
                and isfinite(self.time) and isfinite(latency) and type(self.frame_first) is int
                and type(self.frame_last) is int and type(self.device_time_ms) is int
                and type(self.missed_deadline) is bool):
            return None
        return (f'{{"type":"decision","protocol":{PROTOCOL_VERSION},"instance":{_ascii(self.instance)},'
                f'"class":{_ascii(self.cls)},"time":{self.time!r},'
                f'"scores":{{{",".join(parts)}}},"latency_us":{latency!r},"model_id":{_ascii(self.model_id)},'
                f'"frame_first":{self.frame_first!r},"frame_last":{self.frame_last!r},'
                f'"device_time_ms":{self.device_time_ms!r},"missed_deadline":{"true" if self.missed_deadline else "false"}}}')


@dataclass
class ModelAnnouncement:
    """A model starts serving (a ``"type": "model"`` line): at start-up and at every swap."""

    time: float
    """Wall-clock time (Unix seconds) when the model started serving."""
    model_id: str
    model_version: int
    """1 for the first model this daemon serves, +1 at each swap (like a serving system's versions)."""
    previous_model_id: str | None
    model_file: str
    classes: list[str]
    trained: str | None = None
    """The training date from the model's metadata, if it has one."""
    instance: str = ""
    """Which daemon serves it (runtime.instance_name); the SinkSet stamps it."""

    @classmethod
    def of(cls, model: Any, version: int, previous: Any) -> ModelAnnouncement:
        """For a loaded model (runtime/model.py LoadedModel) that replaces ``previous`` (or None)."""
        date = (getattr(model.meta, "training", None) or {}).get("date")
        return cls(time=time.time(), model_id=model.model_id, model_version=version,
                   previous_model_id=None if previous is None else previous.model_id,
                   model_file=Path(model.path).name, classes=list(model.meta.classes),
                   trained=None if date is None else str(date))

    def to_json(self) -> str:
        d = {"type": "model", "protocol": PROTOCOL_VERSION, "instance": self.instance,
             **{k: v for k, v in asdict(self).items() if k != "instance"}}
        return json.dumps(d, separators=(",", ":"), allow_nan=False)


class Line(Protocol):
    """What ``SinkSet`` sends: an ``Event``, a ``ModelAnnouncement``, a shadow line (runtime.shadow)."""

    instance: str
    model_id: str

    def to_json(self) -> str: ...


class Sink:
    """Base: ``send(line)``; failures are counted in ``errors``."""

    name = "sink"
    failures: tuple[type[BaseException], ...] = (OSError, ValueError)
    """What a failed send raises (counted and logged, never passed on)."""

    def __init__(self) -> None:
        self.sent = 0
        self.errors = 0
        self.problem: str | None = None
        """Why this sink does not work as meant while it still sends (the health view shows it), or None."""
        self._last_log = 0.0

    def send(self, line: str, data: bytes) -> None:
        try:
            self._send(line, data)
            self.sent += 1
        except self.failures as exc:
            self.errors += 1
            now = time.monotonic()
            if now - self._last_log > 10.0:  # a dead listener must not flood the journal
                self._last_log = now
                log.warning("sink %s: %s (%d failures so far)", self.name, exc, self.errors)

    def _send(self, line: str, data: bytes) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def health(self, snapshot: dict) -> None:
        """The daemon's health view, about once a second (only the ROS 2 sink uses it)."""

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


class ClosedStdout(io.TextIOBase):
    """Stands for a stdout that was closed when the daemon started (``handover run >&-``): no
    stdout sink is made from it, and ``sinks.stdout = true`` says so in one line."""


def claim_stdout_for_events() -> IO[str]:
    """Reserve the process's stdout for event lines: a stream on the original stdout, while file
    descriptor 1 and ``sys.stdout`` now lead to stderr (a ``ClosedStdout`` when it was closed).

    Why: stdout is a JSON-lines stream that journald or a pipe parses. Anything else written there
    (a library's ``print``, onnxruntime's C++ logger, a warning banner) would corrupt it; after this
    call it lands in the log instead."""
    if sys.stdout is None:  # Python found no file descriptor 1 at start: nothing to claim
        try:
            os.fstat(1)  # taken since by a file this process opened: leave it alone
        except OSError:
            with contextlib.suppress(OSError):
                os.dup2(2, 1)  # so that no file opened later becomes "stdout" by taking descriptor 1
        sys.stdout = sys.stderr
        return ClosedStdout()
    with contextlib.suppress(OSError, ValueError):
        sys.stdout.flush()
    try:
        fd = os.dup(1)
    except OSError:
        sys.stdout = sys.stderr
        return ClosedStdout()
    events = io.TextIOWrapper(io.FileIO(fd, "w"), encoding="utf-8", line_buffering=True)
    with contextlib.suppress(OSError):
        os.dup2(2, 1)
    sys.stdout = sys.stderr
    return events


STDOUT_BACKLOG_BYTES = 256 * 1024
"""Event lines kept for a stdout that does not take them now (a slow reader, a full pipe): about
750 lines. Beyond it lines are dropped and counted; the thread that reads the pads never waits."""


class SinkFull(HandoverError, OSError):
    """A line dropped because its reader is too slow (counted like any failed send)."""


def _file_descriptor(stream: Any) -> int | None:
    """The descriptor under ``stream``, or None for an in-memory stream (tests, embedding)."""
    try:
        return int(stream.fileno())
    except (AttributeError, OSError, ValueError):
        return None


class StdoutSink(Sink):
    """JSON lines on stdout: journald keeps them, a pipe can read them.

    On a real file descriptor the writes never block: the descriptor is put in non-blocking mode,
    what the reader has not taken yet waits in a bounded backlog (retried at each line and at the
    health tick), and a line that does not fit is dropped and counted. Why: a pipe nobody reads
    fills after 64 KB, and a blocking write would then stop detection and SIGTERM with it."""

    name = "stdout"

    def __init__(self, stream: IO[str] | None = None, backlog_bytes: int = STDOUT_BACKLOG_BYTES) -> None:
        super().__init__()
        self.stream = stream
        self.backlog_bytes = int(backlog_bytes)
        self.dropped = 0
        """Lines dropped because the reader was too slow."""
        self._backlog = bytearray()
        self._fd = _file_descriptor(stream) if stream is not None else None
        self._was_blocking: bool | None = None
        if self._fd is not None:
            try:
                with contextlib.suppress(OSError, ValueError):
                    stream.flush()  # anything written through the stream before goes first
                self._was_blocking = os.get_blocking(self._fd)
                os.set_blocking(self._fd, False)
            except OSError:
                self._fd = None

    def _send(self, line: str, data: bytes) -> None:
        if self._fd is None:
            stream = self.stream or sys.stdout
            stream.write(line + "\n")
            stream.flush()
            return
        chunk = data + b"\n"
        if self._backlog:
            self._drain()
        if self._backlog:
            if len(self._backlog) + len(chunk) > self.backlog_bytes:
                self.dropped += 1
                raise SinkFull(f"nobody reads stdout fast enough: {self.dropped} lines dropped, "
                               f"{len(self._backlog)} bytes waiting")
            self._backlog += chunk
            return
        try:
            n = os.write(self._fd, chunk)
        except BlockingIOError:
            n = 0
        if n < len(chunk):
            self._backlog += chunk[n:]  # the rest of a line begun must follow it, or the stream breaks

    def _drain(self) -> None:
        """Write what the backlog holds as far as the reader takes it now (never waits)."""
        while self._backlog:
            try:
                n = os.write(self._fd, self._backlog)
            except BlockingIOError:
                return
            except OSError:
                self._backlog.clear()  # a closed pipe: nothing will ever take it
                raise
            del self._backlog[:n]

    def health(self, snapshot: dict) -> None:
        if self._fd is not None and self._backlog:
            with contextlib.suppress(OSError):
                self._drain()

    def flush(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                self._drain()
            return
        with contextlib.suppress(OSError, ValueError):
            (self.stream or sys.stdout).flush()

    def close(self) -> None:
        """What the reader did not take is dropped, counted and said in one line (a reader that
        never read would otherwise lose the last events without a word); the descriptor's mode is
        given back."""
        if self._fd is None:
            return
        with contextlib.suppress(OSError):
            self._drain()
        if self._backlog:
            lost = max(1, self._backlog.count(b"\n"))
            self.dropped += lost
            self._backlog.clear()
            log.warning("sink stdout: %d event lines the reader had not taken were dropped at stop "
                        "(%d dropped in all); read the daemon's stdout, or turn [sinks] stdout off", lost, self.dropped)
        if self._was_blocking:
            with contextlib.suppress(OSError):
                os.set_blocking(self._fd, True)
        self._fd = None


class UdpSink(Sink):
    """One JSON datagram per event to host:port (a ROS node or any process can listen).

    A host name is looked up off the loop (runtime.name_resolver): until it resolves, sends to
    it are counted as failed; the daemon never waits for DNS."""

    def __init__(self, host: str, port: int, resolve: Any = None) -> None:

        super().__init__()
        self.name = f"udp://{host}:{port}"
        self.sock: socket.socket | None = None
        self.address: Any = None
        self.target = ResolvedTarget(host, port, self._resolved, resolve=resolve)

    def _resolved(self, family: int, address: tuple) -> None:
        sock = socket.socket(family, socket.SOCK_DGRAM)
        sock.setblocking(False)
        self.sock, self.address = sock, address  # the socket first: a send sees both or neither

    def _send(self, line: str, data: bytes) -> None:
        sock, address = self.sock, self.address
        if sock is None or address is None:
            why = self.target.error or "still being looked up"
            raise OSError(f"host {self.target.host} not resolved ({why}); event not sent")
        sock.sendto(data, address)

    def close(self) -> None:
        self.target.close()
        if self.sock is not None:
            self.sock.close()


class UnixDatagramSink(Sink):
    """One JSON datagram per event to a Unix datagram socket (``@name`` = abstract namespace)."""

    def __init__(self, path: str) -> None:
        super().__init__()
        self.name = f"unix:{path}"
        self.address = "\0" + path[1:] if path.startswith("@") else path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.setblocking(False)

    def _send(self, line: str, data: bytes) -> None:
        self.sock.sendto(data, self.address)

    def close(self) -> None:
        self.sock.close()


class RobotCommands(Protocol):
    """What the robot may tell the daemon from another thread; queued for the hot path's next frame."""

    def set_grasp(self, closed: bool, source: str = "") -> None: ...

    def set_arm_moving(self, moving: bool, source: str = "") -> None: ...

    def outcome(self, word: str, source: str = "") -> None: ...


class PadFrames(Protocol):
    """The frames the ROS 2 node publishes as pad images (read from its own thread)."""

    latest_frame: Any
    layout: Any


@dataclass(frozen=True)
class DaemonSide:
    """All the ROS 2 node sees of the daemon: commands in, frames out, the device's name for diagnostics."""

    commands: RobotCommands
    frames: PadFrames
    hardware_id: str = ""


class SinkSet:
    """All configured sinks; ``emit(event)`` serialises once and sends to each."""

    def __init__(self, sinks: Iterable[Sink], instance: str = "") -> None:
        self.sinks = list(sinks)
        self._lock = threading.Lock()  # held while a line goes out: the shadow thread sends through these sinks too
        self.instance = instance
        """Stamped on every line that has none (runtime.instance_name: which daemon sent it)."""
        self.invalid = 0
        """Events refused because they could not be serialised as JSON (NaN or infinite numbers)."""
        self._last_invalid_log = 0.0

    @classmethod
    def from_config(cls, cfg: SinksConfig, stream: IO[str] | None = None, ros2: Ros2Config | None = None,
                    side: Any = None, instance: str = "") -> SinkSet:
        """Build from a SinksConfig; a UDP host name is looked up in the background (never waited for).

        ROS 2 comes last, only when ``cfg.ros2`` (its ``[ros2]`` section and ``side``, the daemon's
        ``runtime.ros2.DaemonSide``, are then needed); rclpy is imported only then."""

        sinks: list[Sink] = []
        if cfg.stdout and isinstance(stream, ClosedStdout):
            then = "events go to the other sinks only" if cfg.n_without_ros2 > 1 or cfg.ros2 else "no event goes anywhere"
            log.error("sinks.stdout: stdout was closed when the daemon started; %s (start it with stdout open, "
                      "or set sinks.stdout = false)", then)
        elif cfg.stdout:
            sinks.append(StdoutSink(stream))
        for target in cfg.udp:
            sinks.append(UdpSink(*parse_host_port(target)))
        for path in cfg.unix:
            sinks.append(UnixDatagramSink(path))
        if cfg.ros2:
            from runtime.config import Ros2Config
            from runtime.ros2 import open_ros2_sink

            ros = open_ros2_sink(ros2 or Ros2Config(), side, others=len(sinks))
            if ros is not None:
                sinks.append(ros)
        return cls(sinks, instance)

    def emit(self, message: Line) -> bool:
        """Serialise once and send to every sink; False (counted, logged rate-limited) when the
        message is not valid JSON (NaN or infinite numbers) and nothing was sent."""
        encoded = self.encode(message)
        if encoded is None:
            return False
        self.send(*encoded)
        return True

    def encode(self, message: Line) -> tuple[str, bytes] | None:
        """The line and its bytes, or None (counted, logged rate-limited) when it is not valid JSON."""
        if not message.instance:
            message.instance = self.instance
        try:
            line = message.to_json()
        except (TypeError, ValueError) as exc:
            self.invalid += 1
            now = time.monotonic()
            if now - self._last_invalid_log > 10.0:
                self._last_invalid_log = now
                log.error("event of model %s not sent: %s (%d refused so far)", message.model_id, exc, self.invalid)
            return None
        return line, line.encode()

    def send(self, line: str, data: bytes) -> None:
        """An encoded line to every sink (``emit`` = ``encode`` + ``send``; the daemon times them apart)."""
        with self._lock:
            for sink in self.sinks:
                sink.send(line, data)

    def health(self, snapshot: dict) -> None:
        with self._lock:
            for sink in self.sinks:
                sink.health(snapshot)

    @property
    def errors(self) -> int:
        return sum(s.errors for s in self.sinks)

    @property
    def problem(self) -> str | None:
        """The first sink's ``problem``, or None."""
        return next((s.problem for s in self.sinks if s.problem), None)

    def flush(self) -> None:
        with self._lock:
            for sink in self.sinks:
                sink.flush()

    def close(self) -> None:
        with self._lock:
            for sink in self.sinks:
                sink.flush()
                sink.close()


