"""Where each microsecond of a decision goes: a stage table from frame bytes to the sink's send.

The real parts in this process: each frame of a dense synthetic stream is fed as its RLE packet
to the real client (``DSAClient``: parse with CRC, decode, plausibility), read the way the
daemon's loop reads it and handed to the daemon's ``Detector`` serving the model; its decisions go
through the daemon's ``Reporter`` to a UDP socket; a ``runtime.listeners`` listener collects the
stamps of each decision (window, inference, output check, event build, serialisation, sink send).
Nothing is copied or swapped.

Two rhythms:

- back to back: frames fed as fast as the hot path takes them (warm caches);
- paced at 32 Hz: the frame that completes a window arrives one nominal sample period (``firmware_io.frame_timing``) after
  the frame before it, and the detector waits for it as in service (a blocking read). The frames between
  windows (which only push and test the trigger) are fed back to back, so a run of a minute
  yields enough decisions for a p99.9.

The graph alone is timed on the same windows (``comparators``), back to back in its own warm block
(``solo``: what a decision costs when it is the only work, as in the daemon) and paced.
"""

from __future__ import annotations

import gc
import socket
import time
from pathlib import Path

import numpy as np

from firmware_io.frame_timing import NOMINAL_PERIOD_S
from firmware_io.transports.base import Transport
from runtime.listeners import DecisionTimings, FrameListener
from trainer.measure import cycling, percentiles, time_calls

STAGES = ("receive", "ring_trigger", "window", "inference", "output_check", "event_build", "serialise", "sink_send")
"""The stage table's rows, in the order a frame goes through them."""


class _Decisions(FrameListener):
    def __init__(self) -> None:
        self.timings: list[tuple[int, DecisionTimings]] = []

    def on_decision(self, decision) -> None:
        self.timings.append((decision.frame.number, decision.timings))


def _encoded(recording) -> list[bytes]:
    from firmware_io.wire.frames import encode_frame

    stamps = np.rint(recording.timestamps * 1000).astype(np.int64)
    return [encode_frame(f, int(t) & 0xFFFFFFFF, rle=True) for f, t in zip(recording.frames, stamps, strict=True)]


class PacketFeed(Transport):
    """The stream's frame packets, one a read, as a device link delivers them: at once (back to
    back), or, for a packet in ``paced``, one sample period after the read before it (the read
    blocks like a select until then, or returns nothing when given no time)."""

    url = "bench://packets"

    def __init__(self, packets: list[bytes], paced: frozenset[int] = frozenset()) -> None:
        self.packets, self.paced, self.next = packets, paced, 0
        self._due: float | None = None
        self._last = time.perf_counter()

    @property
    def done(self) -> bool:
        return self.next >= len(self.packets)

    def read(self, max_bytes: int = 0, timeout: float = 0.1) -> bytes:
        if self.done:
            return b""
        if self.next in self.paced:
            if self._due is None:
                self._due = self._last + NOMINAL_PERIOD_S
            if not arrived(self._due, timeout):
                return b""
            self._due = None
        packet = self.packets[self.next]
        self.next += 1
        self._last = time.perf_counter()
        return packet

    def write(self, data: bytes) -> None:
        pass

    def close(self) -> None:
        self._closed = True


def feed(model, recording, packets: list[bytes], pace_frames: frozenset[int] = frozenset(),
         mode: str = "trigger", rehearse: bool = True, shadow: Path | None = None, raw: list | None = None,
         capture: Path | None = None) -> dict:
    """Feed every packet through the real client (``DSAClient``: parse, CRC, decode, plausibility), a
    fresh detector and the daemon's reporter to a UDP socket, read the way the daemon's loop reads;
    the packets in ``pace_frames`` arrive one sample period after the one before; ``rehearse``: the
    model rehearsed before them as the daemon does (runtime/rehearsal.py). Each decision is offered to
    the daemon's ``Shadow`` as ``Daemon._decided`` does: with ``shadow`` (a folder holding a candidate)
    the candidate runs in its thread, else none is configured; with ``capture`` (a folder) the daemon's field
    capture sees every frame and decision, as ``Daemon.handle_frame`` calls its listeners. Per-stage
    microseconds of each decision (and the shadow's and capture's counts); ``raw`` gets each decision's
    frame parsed -> decision."""
    from firmware_io.client import DSAClient
    from runtime.daemon import READ_TIMEOUT_S
    from runtime.heap import settle_heap
    from runtime.rehearsal import RehearsedReads
    from trainer.bench.throughput import serving_detector, udp_reporter

    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    sink.setblocking(False)
    detector = serving_detector(model, recording.layout, mode=mode)
    reporter = udp_reporter(sink.getsockname()[1])
    link = PacketFeed(packets, pace_frames)
    client = DSAClient.already_streaming(link, recording.layout)
    recorder = _Decisions()
    reporter.listeners.append(recorder)
    beside = shadow_beside(detector, reporter, shadow)
    listeners = capture_beside(detector, reporter, capture)
    settle_heap()  # as Daemon.run does once started
    step, report, offer, clock = detector.feed, reporter.report, beside.offer, time.perf_counter
    read = RehearsedReads(client.read_frame, detector, READ_TIMEOUT_S, rehearse)
    marks = np.zeros((len(packets), 3))
    try:
        while not link.done:
            frame = read()
            if frame is None:
                continue
            t1 = clock()
            for listener in listeners:
                listener.on_frame(frame)
            decision = step(frame)
            if decision is not None:
                report(decision)
                offer(decision, detector.ring)
            marks[frame.number] = frame.received, t1, clock()
            if frame.number % 64 == 0:
                _drain(sink)
    finally:
        gc.unfreeze()
        beside.stop()
        for listener in listeners:
            listener.close()
        reporter.sinks.close()
    _drain(sink)
    sink.close()
    if raw is not None:
        raw.extend((t.decided - t.received) * 1e6 for _, t in recorder.timings)
    table = _stage_table(marks, recorder.timings)
    if shadow is not None:
        view = beside.counters()["shadow"]
        table["shadow"] = {k: view[k] for k in ("windows_compared", "windows_dropped", "latency_p50_us", "latency_p99_us")}
    if listeners:
        table["capture"] = listeners[0].counters()
    return table


def capture_beside(detector, reporter, folder: Path | None) -> list:
    """The daemon's field capture on a fed detector, writing into ``folder`` (None: no capture, no listener)."""
    if folder is None:
        return []
    from runtime.capture import FieldCapture
    from runtime.capture_writer import CaptureWriter

    capture = FieldCapture(CaptureWriter(folder, max_mb=64).start(), detector, "bench")
    reporter.listeners.append(capture)
    return [capture]


def shadow_beside(detector, reporter, folder: Path | None):
    """The daemon's ``Shadow`` for a fed detector: the candidate in ``folder`` running (None: no shadow
    configured, ``offer`` returns at once, as in a daemon without ``[model] shadow``)."""
    from runtime.config import config_from_dict
    from runtime.health import Health
    from runtime.model import load_model
    from runtime.quarantine import QuarantineStore
    from runtime.shadow import Shadow

    cfg = config_from_dict({"model": {"shadow": str(folder), "poll_interval_s": 0.05}} if folder else {})
    shadow = Shadow(cfg, Health(), lambda p: load_model(p, warm_up=False), lambda m: None, QuarantineStore(),
                    lambda: detector.model, reporter.sinks.emit)
    shadow.start()
    deadline = time.monotonic() + 60
    while folder is not None and shadow.candidate is None and time.monotonic() < deadline:
        time.sleep(0.01)
    if folder is not None and shadow.candidate is None:
        raise RuntimeError(f"the candidate in {folder} did not start in shadow within 60 s")
    return shadow


def _drain(sock: socket.socket) -> None:
    try:
        while sock.recv(65536):
            pass
    except BlockingIOError:
        pass


def _stage_table(marks: np.ndarray, timings: list[tuple[int, DecisionTimings]]) -> dict:
    rows: dict[str, list[float]] = {s: [] for s in (*STAGES, "total", "daemon_internal")}
    for number, t in timings:
        t0, t1, _ = marks[number]
        rows["daemon_internal"].append((t.decided - t.received) * 1e6)  # every decision, reported or not
        reported = t.sent is not None  # no event (continuous mode between reports): the stages up to the check
        cuts = (t0, t1, t.started, t.windowed, t.decided, t.checked, t.built, t.serialised, t.sent)[: 9 if reported else 6]
        for name, a, b in zip(STAGES, cuts[:-1], cuts[1:], strict=False):
            rows[name].append((b - a) * 1e6)
        if reported:
            rows["total"].append((t.sent - t0) * 1e6)
    decided = {n for n, _ in timings}
    quiet = [(m[2] - m[1]) * 1e6 for i, m in enumerate(marks) if i not in decided]
    out = {name: percentiles(v) for name, v in rows.items()}
    out["handle_frame_no_decision"] = percentiles(quiet)
    return out


def decision_frames(model, recording) -> frozenset[int]:
    """The frames whose arrival completes a window (a back-to-back pass of the same detector)."""
    from firmware_io.client import Frame
    from trainer.bench.throughput import serving_detector

    feed = serving_detector(model, recording.layout).feed
    return frozenset(number for number, values in enumerate(recording.frames)
                     if feed(Frame(number, number * 31, time.perf_counter(), values)) is not None)


def stage_tables(model, recording, paced_decisions: int, continuous_model=None) -> dict:
    """Back to back over the whole stream, and paced at 32 Hz for ``paced_decisions`` windows (rehearsed
    as the daemon does, and not: what the rehearsal buys, in the same process); with a
    ``continuous_model`` (a dormant class), continuous mode paced at 32 Hz for as many frames (every
    frame a decision, each one sample period after the one before)."""
    packets = _encoded(recording)
    due = decision_frames(model, recording)
    feed(model, recording, packets[: min(len(packets), 500)])  # warm-up pass, discarded
    fast = feed(model, recording, packets)
    last = sorted(due)[min(len(due), paced_decisions) - 1] if due else 0
    paced = feed(model, recording, packets[: last + 1], frozenset(due))
    cold = feed(model, recording, packets[: last + 1], frozenset(due), rehearse=False)
    out = {"back_to_back": fast, "paced_32hz": paced, "paced_32hz_not_rehearsed": cold, "decisions": len(due)}
    if continuous_model is not None:
        n = min(len(packets), paced_decisions + continuous_model.meta.T)
        out["continuous_paced_32hz"] = feed(continuous_model, recording, packets[:n], frozenset(range(1, n)),
                                            mode="continuous")
    return out


def declared_dormant(model_path: Path, out: Path, dormant: str) -> Path:
    """A copy of ``model_path`` whose metadata names ``dormant`` its dormant class, so that continuous
    mode serves it. For timing only: the graph is the same, and what the classes mean does not change
    how long a decision takes."""
    from trainer.measure import with_metadata

    return with_metadata(model_path, out, lambda meta: meta.update(dormant_class=dormant))


# -- the graph alone, one window at a time -------------------------------------------------------------
def comparators(model) -> dict:
    """name -> callable(window [T, C] float32): the graph as the daemon runs it."""
    return {"onnxruntime": lambda w: model.run_trusted(w[None])}


def compare(fns: dict, windows: np.ndarray, rounds: int, paced: bool) -> dict:
    """Each implementation on the same windows, interleaved (noise hits all alike); us per decision."""
    times = {name: np.empty(rounds) for name in fns}
    clock = time.perf_counter_ns
    for fn in fns.values():  # warm-up
        for w in windows[:20]:
            fn(w)
    for i in range(rounds):
        w = windows[i % len(windows)]
        for name, fn in fns.items():
            if paced:
                time.sleep(NOMINAL_PERIOD_S / len(fns))
            t0 = clock()
            fn(w)
            times[name][i] = (clock() - t0) / 1000.0
    return {name: percentiles(v) for name, v in times.items()}


def solo(fns: dict, windows: np.ndarray, rounds: int) -> dict:
    """Each implementation alone, back to back over the same windows (warm caches: nothing else runs
    between its calls); us per decision. The absolute figures of the graph come from here."""
    return {name: percentiles(time_calls(cycling(fn, windows), rounds)) for name, fn in fns.items()}


def paced_alone(fn, windows: np.ndarray, rounds: int, rehearsed: bool) -> dict:
    """One implementation alone, paced at 32 Hz, the thread asleep until the frame arrives (as the daemon
    waits); ``rehearsed``: the window decided once ``REHEARSAL_LEAD_S`` before the frame, then asleep
    until it, as the daemon rehearses (runtime/rehearsal.py)."""
    from runtime.detector import REHEARSAL_LEAD_S

    times = np.empty(rounds)
    clock = time.perf_counter_ns
    for i in range(rounds):
        w = windows[i % len(windows)]
        due = time.perf_counter() + NOMINAL_PERIOD_S
        if rehearsed:
            arrived(due - REHEARSAL_LEAD_S, NOMINAL_PERIOD_S)
            fn(windows[(i + 1) % len(windows)])
        arrived(due, NOMINAL_PERIOD_S)
        t0 = clock()
        fn(w)
        times[i] = (clock() - t0) / 1000.0
    return percentiles(times)


def arrived(at: float, timeout: float) -> bool:
    """Whether a frame due at ``perf_counter() == at`` is in, after blocking like a select for at
    most ``timeout`` (none: a poll)."""
    left = at - time.perf_counter()
    if left > 0 and timeout > 0:
        time.sleep(min(timeout, left))
    return time.perf_counter() >= at
