"""Throughput and footprint: replay rate, the daemon's memory and CPU share at 32 Hz, start-up
time to READY, and the time to swap a model.

- replay: a dense synthetic stream (simulated trial windows back to back, each followed by just
  enough untouched frames for the daemon's trigger to re-arm), pre-encoded as RLE packets, through
  StreamParser + decode + plausibility and the daemon's ``Detector.feed`` (ring, trigger, model,
  output check; no socket) as fast as possible; and the real Daemon reading
  ``replay://FILE?speed=max`` (its emulator encodes the frames in the same thread, so this
  figure is a lower bound).
- footprint: ``handover run`` as a child process against the TCP emulator (another process) at
  real speed; RSS from /proc/PID/status, CPU share = (utime + stime) / wall over the run.
- start-up: from spawning ``handover run`` to its READY=1 on a NOTIFY_SOCKET we listen on.
- swap: during the footprint run a new model file is renamed into the folder; time from the
  rename to the daemon's "swapped in" log line and to its first event with the new model id.
"""

from __future__ import annotations

import os
import socket
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from firmware_io.frame_timing import NOMINAL_PERIOD_S, NOMINAL_RATE_HZ
from runtime.listeners import FrameListener
from trainer.bench import harness
from trainer.defaults import describe_default
from trainer.measure import (
    load_average,
    run_facts,
    tap_gap,
    tap_stream,
    train_default_model,
    with_metadata,
    write_results,
)

NAME = "throughput"


def serving_detector(model, layout, mode: str = "trigger"):
    """The daemon's ``Detector`` serving ``model`` for ``layout`` (its pads, default trigger, or ``mode``
    ``continuous``), fed by the caller."""
    from runtime.config import SceneConfig
    from runtime.detector import Detector

    detector = Detector(SceneConfig(pads=",".join(str(p) for p in model.meta.pads), mode=mode))
    detector.swap(model, layout)
    return detector


def udp_reporter(udp_port: int | None = None):
    """The daemon's ``Reporter`` sending each reported decision to a UDP port (None: to no sink)."""
    from runtime.config import SinksConfig
    from runtime.reporter import Reporter
    from runtime.sinks import SinkSet

    udp = (f"127.0.0.1:{udp_port}",) if udp_port else ()
    return Reporter(SinkSet.from_config(SinksConfig(stdout=False, udp=udp)))


def replay_hot_path(model, recording, repeats: int = 1) -> dict:
    """Frames per second through the client's steps (parser + CRC + decode + plausibility) and the
    daemon's ``Detector.feed`` (ring, trigger, inference, output check), no socket."""
    from firmware_io.client import Frame
    from firmware_io.plausibility import FrameCheck
    from firmware_io.wire.frames import decode_frame_payload, encode_frame
    from firmware_io.wire.packets import PacketId
    from firmware_io.wire.parser import StreamParser

    layout = recording.layout
    n = layout.n_taxels
    stream = b"".join(encode_frame(f, int(i * 31), rle=True) for i, f in enumerate(recording.frames))
    chunks = [stream[i : i + 4096] for i in range(0, len(stream), 4096)]
    frame_id = int(PacketId.FULL_FRAME)
    check = FrameCheck(layout)
    best = None
    for _ in range(repeats):
        parser = StreamParser(n)
        feed = serving_detector(model, layout).feed
        number = decisions = 0
        t0 = time.perf_counter()
        for chunk in chunks:
            for pkt in parser.feed(chunk):
                if pkt.packet_id != frame_id:
                    continue
                stamp, values = decode_frame_payload(pkt.payload, n)
                if check.problem(values) is None:
                    decisions += feed(Frame(number, stamp, pkt.received, values)) is not None
                    number += 1
        seconds = time.perf_counter() - t0
        if best is None or seconds < best[0]:
            best = (seconds, number, decisions)
    seconds, frames, decisions = best
    return {"frames": frames, "decisions": decisions, "seconds": seconds, "frames_per_s": frames / seconds,
            "bytes": len(stream)}


class _Span(FrameListener):
    """When the daemon handled its first and its last frame; stops it after the last."""

    def __init__(self, daemon, last: int) -> None:
        self.daemon, self.last, self.marks = daemon, last, {}

    def on_frame(self, frame) -> None:
        if frame.number == 0:
            self.marks["first"] = time.perf_counter()
        if frame.number >= self.last:
            self.marks["last"] = time.perf_counter()
            self.daemon.request_stop()


def replay_daemon(model_path: Path, recording, work: Path) -> dict:
    """The real Daemon reading replay://FILE?speed=max; frames/s from its first to its last frame."""
    from runtime.config import Config, DeviceConfig, ModelConfig, SceneConfig, SinksConfig
    from runtime.daemon import Daemon
    from runtime.sdnotify import Notifier

    path = recording.save(work / "stream.hrec")
    models = work / "models-replay"
    harness.install_model(model_path, models)
    cfg = Config(device=DeviceConfig(url=f"replay://{path}?speed=max"), scene=SceneConfig(pads="all"),
                 model=ModelConfig(folder=str(models)), sinks=SinksConfig(stdout=False), log_level="error")
    daemon = Daemon(cfg, notifier=Notifier({}))
    last = recording.n_frames - 1
    span = _Span(daemon, last)
    daemon.listeners.append(span)
    stopper = threading.Timer(120, daemon.request_stop)
    stopper.start()
    try:
        daemon.run()
    finally:
        stopper.cancel()
    marks = span.marks
    if "last" not in marks:
        raise RuntimeError("the daemon did not get through the replay within 120 s")
    seconds = marks["last"] - marks["first"]
    return {"frames": last, "decisions": int(daemon.health.decisions), "seconds": seconds,
            "frames_per_s": last / seconds}


def _proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def proc_mem_mb(pid: int) -> dict:
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out[key] = int(value.split()[0]) / 1024.0
    return out


class _NotifySocket:
    """A NOTIFY_SOCKET we own: records when READY=1 arrives."""

    def __init__(self, folder: Path) -> None:
        self.path = folder / "notify.sock"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(self.path))

    def wait_ready(self, timeout: float) -> float | None:
        deadline = time.perf_counter() + timeout
        while (left := deadline - time.perf_counter()) > 0:
            self.sock.settimeout(left)
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                return None
            if b"READY=1" in data.split(b"\n"):
                return time.perf_counter()
        return None

    def close(self) -> None:
        self.sock.close()
        self.path.unlink(missing_ok=True)


def startup(model_path: Path, work: Path, runs: int) -> dict:
    """Spawn -> READY=1 of ``handover run`` (model loaded and warmed up; device connects after)."""
    emulator = harness.EmulatorProcess(tap_stream(quick=True, n_windows=4, gap=tap_gap()), 1.0)
    models = work / "models-start"
    harness.install_model(model_path, models)
    config = harness.write_config(work, emulator.url, models, None)
    times = []
    try:
        for _ in range(runs):
            notify = _NotifySocket(work)
            t0 = time.perf_counter()
            proc = harness.spawn_daemon(config, env={"NOTIFY_SOCKET": str(notify.path)})
            ready = notify.wait_ready(60)
            harness.stop_daemon(proc)
            notify.close()
            if ready is None:
                raise RuntimeError(f"handover run sent no READY=1 within 60 s: {proc.stderr.read()[-300:]}")
            times.append(ready - t0)
    finally:
        emulator.close()
    return {"runs": len(times), "seconds": times, "median_s": float(np.median(times)), "max_s": float(max(times))}


def footprint_and_swap(model_path: Path, second_model: Path, work: Path, duration: float, seed: int = 0,
                        quick: bool = False) -> dict:
    """``handover run`` at 32 Hz: RSS, CPU share, and a model swap in the middle."""
    n_windows = max(6, int(duration * 32 / (15 + tap_gap())))
    stream = tap_stream(seed, quick, n_windows=n_windows, gap=tap_gap())
    listener = harness.UdpListener()
    emulator = harness.EmulatorProcess(stream, 1.0)
    models = work / "models-run"
    harness.install_model(model_path, models, "a.onnx")
    config = harness.write_config(work, emulator.url, models, listener.port, log_level="info", poll_s=0.5)
    proc = harness.spawn_daemon(config)
    log_lines: list[tuple[float, str]] = []

    def read_log() -> None:
        for line in proc.stderr:
            log_lines.append((time.perf_counter(), line.rstrip()))

    reader = threading.Thread(target=read_log, daemon=True)
    reader.start()
    try:
        give_up = time.perf_counter() + 60
        while not listener.events and proc.poll() is None and time.perf_counter() < give_up:
            time.sleep(0.05)  # serving once the first event is seen
        t0, cpu0 = time.perf_counter(), _proc_cpu_s(proc.pid)
        time.sleep(duration / 2)
        old_ids = {e.get("model_id") for _, e in listener.events}
        t_rename = time.perf_counter()
        harness.install_model(second_model, models, "b.onnx")
        time.sleep(duration / 2)
        t1, cpu1 = time.perf_counter(), _proc_cpu_s(proc.pid)
        mem = proc_mem_mb(proc.pid)
    finally:
        harness.stop_daemon(proc)
        emulator.close()
        listener.close()
        reader.join(2)
    new_events = [t for t, e in listener.events if t > t_rename and e.get("model_id") not in old_ids]
    swap_log = [t for t, line in log_lines if "swapped in" in line and t > t_rename]
    return {"rss_mb": mem.get("VmRSS"), "rss_peak_mb": mem.get("VmHWM"), "cpu_share": (cpu1 - cpu0) / (t1 - t0),
            "cpu_seconds": cpu1 - cpu0, "wall_seconds": t1 - t0, "events": len(listener.events),
            "swap_to_log_s": (swap_log[0] - t_rename) if swap_log else None,
            "swap_to_first_event_s": (new_events[0] - t_rename) if new_events else None,
            "poll_interval_s": 0.5, "window_every_s": (15 + tap_gap()) * NOMINAL_PERIOD_S}


def variant_model(model_path: Path, folder: Path) -> Path:
    """The same graph with one metadata field changed: a different file, so a different model id."""
    return with_metadata(model_path, folder / "variant.onnx", lambda meta: meta["training"].update(variant="bench swap"))


def run(args) -> dict:
    from runtime.model import load_model

    say = args.say
    load_before = load_average()
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="handover-throughput-") as tmp:
        work = Path(tmp)
        say("throughput: training the default model on the simulated protocol (synthetic) ...")
        model_path = train_default_model(work, seed=args.seed, quick=args.quick)
        model = load_model(model_path, intra_op_threads=1, allow_spinning=False)
        stream = tap_stream(args.seed, args.quick, n_windows=40 if args.quick else 1000, gap=tap_gap())
        say(f"throughput: replay of {stream.n_frames} frames through the hot path ...")
        hot = replay_hot_path(model, stream, repeats=1 if args.quick else 3)
        say("throughput: replay through the daemon (replay://, speed=max) ...")
        daemon = replay_daemon(model_path, stream, work)
        say("throughput: start-up to READY=1 ...")
        start = startup(model_path, work, runs=1 if args.quick else 5)
        duration = 3.0 if args.quick else 30.0
        say(f"throughput: handover run at 32 Hz for {duration:.0f} s (RSS, CPU share, model swap) ...")
        foot = footprint_and_swap(model_path, variant_model(model_path, work), work, duration, args.seed, args.quick)
    result = {
        "synthetic": True,
        "replay_hot_path": hot,
        "replay_daemon": daemon,
        "startup": start,
        "footprint": foot,
        "window_period_frames": 15 + tap_gap(),
        "replay_frames_per_s": hot["frames_per_s"],
        "replay_daemon_frames_per_s": daemon["frames_per_s"],
        "rss_mb": foot["rss_mb"],
        "cpu_share": foot["cpu_share"],
        "startup_to_ready_s": start["median_s"],
        "swap_s": foot["swap_to_first_event_s"],
        **run_facts(NAME, args, load_before, t_start),
    }
    write_results(args.out, NAME, result, markdown(result))
    return result


def _s(v: float | None, unit: str = "s", digits: int = 2) -> str:
    return "-" if v is None else f"{v:.{digits}f} {unit}"


def markdown(res: dict) -> list[str]:
    h, d, st, f = res["replay_hot_path"], res["replay_daemon"], res["startup"], res["footprint"]
    return [
        "# Throughput and footprint (synthetic data)", "",
        f"Stream: simulated trial windows back to back (one inference every {res['window_period_frames']} frames: "
        "about the most a "
        f"threshold-triggered daemon does at 32 Hz). Default model ({describe_default()}).", "",
        "| figure | value |", "|---|---|",
        f"| replay, hot path (parser + decode + plausibility, then the real Daemon.handle_frame; no socket) | "
        f"{h['frames_per_s']:,.0f} frames/s ({h['frames']} frames, {h['decisions']} inferences, {h['seconds']:.2f} s; "
        f"{h['frames_per_s'] / NOMINAL_RATE_HZ:,.0f}x real time) |",
        f"| replay, daemon reading replay://?speed=max (emulator encoding in the same thread) | "
        f"{d['frames_per_s']:,.0f} frames/s ({d['frames']} frames, {d['decisions']} decisions) |",
        f"| `handover run` resident memory at 32 Hz (VmRSS / peak VmHWM) | {_s(f['rss_mb'], 'MB', 1)} / "
        f"{_s(f['rss_peak_mb'], 'MB', 1)} |",
        f"| `handover run` CPU share at 32 Hz (CPU time / wall time, {f['wall_seconds']:.0f} s) | "
        f"{100 * f['cpu_share']:.1f} % of one core |",
        f"| start-up, spawn -> READY=1 (median of {st['runs']}, max) | {_s(st['median_s'])} ({_s(st['max_s'])}) |",
        f"| model swap, rename -> \"swapped in\" log line | {_s(f['swap_to_log_s'])} |",
        f"| model swap, rename -> first event with the new model id | {_s(f['swap_to_first_event_s'])} |",
        "",
        f"READY=1 is sent once the model is loaded and warmed up (the device connects after). The swap "
        f"waits for two equal polls of the folder (poll interval {f['poll_interval_s']} s in this run) and the "
        f"first event after it comes with the next window (one every {f['window_every_s']:.2f} s).", "",
        res["note"],
    ]
