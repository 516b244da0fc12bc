"""What the hostile cases share: ``handover`` as a child, its config, an in-process daemon over a model
folder, pressed frames, and the one-line check (a ``handover run`` child: trainer.bench.harness)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np

from firmware_io.frame_timing import nominal_stamp_ms

ROOT = Path(__file__).resolve().parents[1]
HANG_GUARD_S = 30.0
"""How long a case waits for a part that should never block before calling it blocked."""
NOBODY = 65534
"""Another user."""


def cli(argv: list[str], timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    """``handover ARGV`` as a process (stdout and stderr captured as text)."""
    return subprocess.run([sys.executable, "-m", "runtime.cli", *argv], capture_output=True, text=True, cwd=ROOT,
                          timeout=timeout, **kw)


def one_line(text: str, *needles: str) -> bool:
    """Whether ``text`` is exactly one line that names every needle."""
    lines = text.strip().splitlines()
    return len(lines) == 1 and all(n in lines[0] for n in needles)


def sim_config(path: Path, models: Path, rest: str = "", top: str = "", url: str = "sim://") -> Path:
    """A config at ``path``: ``top`` lines, then the device ``url`` and the model folder, then ``rest``."""
    path.write_text(f'{top}[device]\nurl = "{url}"\n[model]\nfolder = "{models}"\n{rest}')
    return path


def read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def wait_until(condition: Callable[[], bool], guard_s: float = HANG_GUARD_S) -> bool:
    deadline = time.monotonic() + guard_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def status_when(path: Path, proc: subprocess.Popen, done: Callable[[dict], bool], guard_s: float) -> dict:
    """The health file at ``path``, read until ``done`` says so, ``proc`` ends or ``guard_s`` passes."""
    status: dict = {}
    deadline = time.monotonic() + guard_s
    while time.monotonic() < deadline and proc.poll() is None:
        status = read_json(path)
        if done(status):
            break
        time.sleep(0.2)
    return status


def folder_daemon(models: Path, health_file: Path, on_event=None, **settings):
    """A Daemon over ``sim://`` fitted to SDH-2, serving the newest file of ``models``; its watcher is
    stopped, so the case polls it. ``settings``: more config keys."""
    from firmware_io.layout import SensorLayout
    from runtime.config import config_from_dict
    from runtime.daemon import Daemon

    cfg = config_from_dict({"device": {"url": "sim://"}, "sinks": {"stdout": False}, "model": {"folder": str(models)},
                            "health_file": str(health_file), **settings})
    daemon = Daemon(cfg, on_event=on_event)
    daemon.detector.fit(SensorLayout.sdh2())
    daemon.models.start()
    daemon.models.watcher.stop()
    return daemon


def serving(daemon) -> str | None:
    """The file name of the model that serves, if one does."""
    return Path(daemon.model.path).name if daemon.model is not None else None


def pressed_frames(layout, numbers: Iterable[int], pressed: Callable[[int], bool], level: int,
                   late_s: float = 0.0) -> Iterator:
    """Frames ``numbers`` at 32 Hz device time, one distal taxel at ``level`` where ``pressed(number)``,
    each received ``late_s`` before it is made."""
    from firmware_io.client import Frame

    column = int(layout.columns("distal")[40])
    for number in numbers:
        values = np.zeros(layout.n_taxels, dtype=np.uint16)
        values[column] = level if pressed(number) else 0
        yield Frame(number, nominal_stamp_ms(number), time.perf_counter() - late_s, values)
