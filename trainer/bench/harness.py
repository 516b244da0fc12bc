"""The end-to-end rig: an emulated DSACON32m in its own process, ``handover run`` in another,
a UDP listener in this one.

The emulator process stamps ``time.perf_counter()`` right before the socket ``send`` that
carries the last byte of each frame (CLOCK_MONOTONIC: the same clock in every process on
Linux), keyed by the frame's device timestamp; the listener stamps each event datagram on
receipt and finds its frame by the event's ``device_time_ms``. Nothing in the emulator or
daemon is edited: a DeviceEmulator subclass records where each frame ends in the byte stream
and a TcpEmulatorServer subclass wraps the accepted socket's ``send``.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing as mp
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path

from firmware_io.emulator.device import DeviceEmulator
from firmware_io.emulator.server import TcpEmulatorServer
from runtime import realtime

ROOT = Path(__file__).resolve().parents[2]


class StampingEmulator(DeviceEmulator):
    """Records, for each frame, its device timestamp and the stream offset of its last byte."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.read_total = 0
        self.frame_ends: deque[tuple[int, int]] = deque()  # (stream offset after the frame, stamp ms)

    def read(self, max_bytes: int = 4096, now: float | None = None) -> bytes:
        out = super().read(max_bytes, now)
        self.read_total += len(out)
        return out

    def _emit_frame(self, now: float) -> None:
        seq = self._next
        super()._emit_frame(now)
        self.frame_ends.append((self.read_total + len(self._out), self.stamp_of(seq)))


class _TimedSocket:
    """A socket whose ``send`` reports how many bytes have left so far, and when."""

    def __init__(self, sock: socket.socket, on_sent) -> None:
        self._sock = sock
        self._on_sent = on_sent
        self.sent_total = 0

    def send(self, data) -> int:
        # Stamped as the bytes are handed to the kernel: on loopback the daemon can be woken and
        # preempt this process inside send(), so a stamp after it can come after the event's arrival.
        t = time.perf_counter()
        n = self._sock.send(data)
        self.sent_total += n
        self._on_sent(self.sent_total, t)
        return n

    def __getattr__(self, name):
        return getattr(self._sock, name)


class StampingServer(TcpEmulatorServer):
    """TcpEmulatorServer that stamps the moment each frame's last byte is written to the socket."""

    def __init__(self, emulator: StampingEmulator, **kwargs) -> None:
        super().__init__(emulator, **kwargs)
        self.sent_at: dict[int, float] = {}
        self._base = 0  # emulator stream offset at which the current connection started

    def _accept(self) -> None:
        before = self._conn
        super()._accept()
        if self._conn is not None and self._conn is not before:
            self.emulator.frame_ends.clear()
            self._base = self.emulator.read_total
            self._conn = _TimedSocket(self._conn, self._on_sent)

    def _on_sent(self, total: int, t: float) -> None:
        ends = self.emulator.frame_ends
        while ends and ends[0][0] - self._base <= total:
            self.sent_at[ends.popleft()[1]] = t


def _serve(recording, speed, pipe, priority: int) -> None:
    """Child process: serve the recording once, then hand the send stamps back. At the daemon's
    real-time ``priority`` (runtime/realtime.py): a real device is hardware, not one more process
    waiting for the CPU."""
    realtime.enter_realtime(priority)
    # the whole recording, however late the daemon asks for frames (the emulator's world runs from then on)
    emulator = StampingEmulator(recording, speed=speed, loop=False, session_starts="first_acquisition")
    server = StampingServer(emulator, host="127.0.0.1", port=0).start()
    pipe.send(server.port)
    while not emulator.finished:
        if pipe.poll(0.05):  # the parent wants to stop early
            break
    time.sleep(0.3)
    server.stop()
    pipe.send(server.sent_at)
    pipe.close()


class EmulatorProcess:
    """The emulator serving ``recording`` at ``speed`` (None = as fast as possible) in a child process."""

    def __init__(self, recording, speed: float | None, priority: int = 0) -> None:
        ctx = mp.get_context("fork")
        self._pipe, child = ctx.Pipe()
        self.process = ctx.Process(target=_serve, args=(recording, speed, child, priority), daemon=True)
        self.process.start()
        if not self._pipe.poll(20):
            raise RuntimeError("the emulator process did not start")
        self.port = int(self._pipe.recv())
        self.url = f"tcp://127.0.0.1:{self.port}"

    def wait_stamps(self, timeout: float) -> dict[int, float]:
        """Frame stamp (device ms) -> perf_counter when its last byte was sent; waits for the end."""
        if not self._pipe.poll(timeout):
            self._pipe.send("stop")
            if not self._pipe.poll(10):
                raise RuntimeError("the emulator process did not finish")
        stamps = self._pipe.recv()
        self.process.join(5)
        return stamps

    def close(self) -> None:
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(2)


class DatagramListener:
    """Receives datagrams on a bound socket in a thread and hands each to ``on_datagram``."""

    def __init__(self, sock: socket.socket, name: str, priority: int = 0) -> None:
        self.sock = sock
        self.priority = priority
        self.sock.settimeout(0.1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def on_datagram(self, data: bytes, t: float) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _run(self) -> None:
        realtime.enter_realtime(self.priority)  # the robot's receiver, at the daemon's priority
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            self.on_datagram(data, time.perf_counter())

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1)
        self.sock.close()


class UdpListener(DatagramListener):
    """Receives decision datagrams in a thread, each with its arrival time (model announcements
    and other line types of docs/EVENTS.md are skipped)."""

    def __init__(self, priority: int = 0) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        self.port = sock.getsockname()[1]
        self.events: list[tuple[float, dict]] = []
        super().__init__(sock, "bench-udp", priority)

    def on_datagram(self, data: bytes, t: float) -> None:
        with contextlib.suppress(ValueError):
            event = json.loads(data)
            if event.get("type") == "decision":
                self.events.append((t, event))


def write_config(folder: Path, device_url: str, model_dir: Path, udp_port: int | None,
                 log_level: str = "warning", poll_s: float = 1.0, realtime_priority: int | None = None) -> Path:
    """A daemon config for the rig: all pads, the UDP listener as the only sink; ``realtime_priority``
    unset: the daemon's default."""
    udp = f'["127.0.0.1:{udp_port}"]' if udp_port else "[]"
    rt = "" if realtime_priority is None else f"realtime_priority = {realtime_priority}\n"
    text = (f'log_level = "{log_level}"\n{rt}\n[device]\nurl = "{device_url}"\nstall_timeout_s = 5.0\n'
            f'reconnect_min_s = 0.2\nreconnect_max_s = 1.0\n\n[scene]\npads = "all"\n\n'
            f'[model]\nfolder = "{model_dir}"\npoll_interval_s = {poll_s}\n\n[sinks]\nstdout = false\nudp = {udp}\n')
    path = folder / "handover.toml"
    path.write_text(text)
    return path


def spawn_daemon(config: Path, env: dict | None = None, stdout=subprocess.DEVNULL,
                 stderr=subprocess.PIPE) -> subprocess.Popen:
    """``handover run --config FILE`` as a child process (stderr piped by default: its log)."""
    full_env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
                **(env or {})}
    return subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", "--config", str(config)], cwd=str(ROOT),
                            env=full_env, stdout=stdout, stderr=stderr, text=True)


def stop_daemon(proc: subprocess.Popen, timeout: float = 5.0) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(2)
    return proc.returncode


def install_model(source: Path, folder: Path, name: str = "model.onnx") -> Path:
    """The safe drop: copy to a dotfile in the folder, chmod 644, rename."""
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f".{name}.tmp"
    tmp.write_bytes(Path(source).read_bytes())
    os.chmod(tmp, 0o644)
    final = folder / name
    os.replace(tmp, final)
    return final


def busy_loop() -> None:  # pragma: no cover - runs in a child process
    while True:
        pass


class CpuLoad:
    """Two busy-loop processes (one per core) while the context is open."""

    def __init__(self, n: int = 2) -> None:
        self.n = n
        self.procs: list = []

    def __enter__(self) -> CpuLoad:
        ctx = mp.get_context("fork")
        self.procs = [ctx.Process(target=busy_loop, daemon=True) for _ in range(self.n)]
        for p in self.procs:
            p.start()
        time.sleep(0.2)
        return self

    def __exit__(self, *exc) -> None:
        for p in self.procs:
            p.terminate()
        for p in self.procs:
            p.join(2)
