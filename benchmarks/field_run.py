"""One day of ``./dev bench field``: ``handover emulate`` plays a scripted session, ``handover run`` serves it
(a model folder, optionally a shadow and a capture folder), and a robot that knows the truth says each
event's outcome on the control socket.

Both are the product's commands in their own processes, as on a robot PC; the "robot" reads the daemon's
event lines, finds the scripted event each answers in ``handover emulate --script-out``'s script (the
device time of the line, as ``handover score`` maps it) and sends ``outcome <true class>`` right after the
line; a report outside every scripted event is a false event: ``outcome dormant``.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from firmware_io.emulator.script_file import SessionScript, read_script
from trainer.field_folder import CLASSES

__all__ = ["Day", "run_day", "truth_of"]

HANDOVER = [sys.executable, "-m", "runtime.cli"]
START_TIMEOUT_S = 60.0
"""Longest wait for the emulator's listening line and for the session to start."""


@dataclass
class Day:
    """What one run gave: the daemon's lines, the script, its health view, what the robot said."""

    lines: list[dict]
    script: SessionScript
    health: dict
    said: Counter = field(default_factory=Counter)
    """Outcome words sent, by word."""
    wall_s: float = 0.0
    log: str = ""
    """The daemon's stderr (warnings), for the report when something went wrong."""

    def of_type(self, kind: str) -> list[dict]:
        return [line for line in self.lines if line.get("type") == kind]

    @property
    def device_s(self) -> float:
        """The session's length in device time."""
        return float(self.script.frame_ms[-1]) / 1000.0 if len(self.script.frame_ms) else 0.0


def truth_of(script: SessionScript, device_time_ms: int) -> str:
    """The class a scripted session shows at ``device_time_ms``: the scripted event's action, or dormant
    outside every event (a false event)."""
    _loop, frame = script.frame_of(device_time_ms)
    for trial in script.trials:
        if trial.first <= frame <= trial.last:
            return trial.action
    return "dormant"


def config_text(url: str, work: Path, models: Path, shadow: Path | None, capture: Path | None,
                idle_every_s: float) -> str:
    """The daemon's config for one day (absolute paths; stdout carries the lines)."""
    text = [f'instance = "field-bench"\nhealth_file = "{work / "status.json"}"\nlog_level = "warning"',
            f'[device]\nurl = "{url}"', f'[model]\nfolder = "{models}"' + (f'\nshadow = "{shadow}"' if shadow else ""),
            f'[control]\nsocket = "{work / "control.sock"}"', "[sinks]\nstdout = true"]
    if capture is not None:
        text.append(f'[capture]\nfolder = "{capture}"\nidle_every_s = {idle_every_s:g}')
    return "\n\n".join(text) + "\n"


class Lines:
    """A process's stdout lines, read by a thread of its own, so a wait has a deadline."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.proc, self.queue = proc, queue.Queue()
        threading.Thread(target=lambda: [self.queue.put(x) for x in proc.stdout] + [self.queue.put(None)],
                         name="field-emulator-out", daemon=True).start()

    def wait_for(self, prefix: str, timeout_s: float) -> str:
        """The rest of the first line starting with ``prefix``; RuntimeError when the process ends or
        ``timeout_s`` passes first."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = self.queue.get(timeout=left)
            except queue.Empty:
                break
            if line is None:
                raise RuntimeError(f"handover emulate ended before saying {prefix!r} (exit {self.proc.poll()})")
            if line.startswith(prefix):
                return line[len(prefix):].strip()
        raise RuntimeError(f"handover emulate did not say {prefix!r} within {timeout_s:.0f} s")


class Robot:
    """Reads the daemon's stdout; says the truth about each decision on the control socket."""

    def __init__(self, daemon: subprocess.Popen, script_path: Path, control: Path) -> None:
        self.daemon, self.script_path, self.control = daemon, script_path, control
        self.lines: list[dict] = []
        self.said: Counter = Counter()
        self.script: SessionScript | None = None
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.thread = threading.Thread(target=self._loop, name="field-robot", daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        for raw in self.daemon.stdout:
            try:
                line = json.loads(raw)
            except ValueError:
                continue
            if not isinstance(line, dict):
                continue
            self.lines.append(line)
            if line.get("type") == "decision":
                self._say(line)

    def _say(self, line: dict) -> None:
        if self.script is None:
            self.script = read_script(self.script_path)  # written with the device time once frames were asked for
        word = truth_of(self.script, int(line["device_time_ms"]))
        if word not in CLASSES:
            return
        try:
            self.sock.sendto(f"outcome {word}".encode(), str(self.control))
            self.said[word] += 1
        except OSError:
            self.said["(not sent)"] += 1


def _length_s(session: Path) -> float:
    from firmware_io.recordings.recording import Recording

    rec = Recording.load(session)
    return float(rec.timestamps[-1] - rec.timestamps[0])


def run_day(work: Path, session: Path, models: Path, speed: float, shadow: Path | None = None,
            capture: Path | None = None, idle_every_s: float = 60.0, say=print) -> Day:
    """Play ``session`` (a recording with one trial per scripted event) once to a daemon; returns its day."""
    work.mkdir(parents=True, exist_ok=True)
    script_path = work / "script.json"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    emulator = subprocess.Popen([*HANDOVER, "emulate", "--listen", "tcp://127.0.0.1:0", "--source", str(session),
                                 "--speed", f"{speed:g}", "--no-loop", "--script-out", str(script_path)],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    out, daemon, robot = Lines(emulator), None, None
    t0 = time.monotonic()
    try:
        url = out.wait_for("listening: ", START_TIMEOUT_S)
        cfg = work / "handover.toml"
        cfg.write_text(config_text(url, work, models, shadow, capture, idle_every_s))
        log = (work / "daemon.log").open("w")
        daemon = subprocess.Popen([*HANDOVER, "run", "--config", str(cfg)], stdout=subprocess.PIPE, stderr=log,
                                  text=True, env=env)
        robot = Robot(daemon, script_path, work / "control.sock")
        out.wait_for("session over", START_TIMEOUT_S + _length_s(session) / speed * 3)
        time.sleep(2.0)  # the last window and its capture margin, in wall time at any speed
    finally:
        for proc in (daemon, emulator):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in (daemon, emulator):
            if proc is not None:
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
    if robot is None:
        raise RuntimeError("the daemon did not start")
    robot.thread.join(timeout=10)
    health_path = work / "status.json"
    health = json.loads(health_path.read_text()) if health_path.is_file() else {}
    day = Day(robot.lines, read_script(script_path), health, robot.said, round(time.monotonic() - t0, 1),
              (work / "daemon.log").read_text(errors="replace")[-4000:])
    say(f"field: {len(day.of_type('decision'))} events, {len(day.of_type('shadow'))} shadow lines, outcomes said "
        f"{dict(day.said)} ({day.wall_s:.0f} s)")
    return day
