"""A hostile world around the daemon: the cases where it could be stalled or steered, each tried
with real parts (pipes, sockets, subprocess daemons, ONNX files) and judged held or not.

``./dev bench hostile`` counts them (results/hostile.md, "The world around the daemon"); the
tests in tests/test_hostile_world.py run each case and name what did not hold. A case returns
``{"held": bool, "detail": str, ...}``; a case that raises counts as not held.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmarks.hostile_files import files_that_eat, full_disk_record
from benchmarks.hostile_locals import (
    device_spellings,
    lying_early_heads,
    squatted_control_name,
    squatted_lock_folder,
    unwritable_health_folder,
)
from benchmarks.hostile_models import write_model
from benchmarks.hostile_parts import (
    HANG_GUARD_S,
    NOBODY,
    ROOT,
    cli,
    folder_daemon,
    one_line,
    pressed_frames,
    read_json,
    serving,
    sim_config,
    status_when,
    wait_until,
)
from firmware_io.frame_timing import NOMINAL_PERIOD_S
from trainer.bench.harness import spawn_daemon, stop_daemon

SMALL_PIPE = 4096
"""A pipe this small fills after about a dozen event lines (a pipe nobody reads, sooner)."""


def _daemon_folders(work: Path) -> tuple[Path, Path]:
    """``work/models`` (the watched folder) and ``work/state`` (config, health file), made."""
    models, state = work / "models", work / "state"
    models.mkdir(parents=True)
    state.mkdir(parents=True)
    return models, state


def _run_config(config: Path, url: str, models: Path, rest: str) -> Path:
    """A ``handover run`` config: the health file beside it, no realtime priority, ``url``, ``models``; then ``rest``."""
    return sim_config(config, models, rest, f'health_file = "{config.parent / "status.json"}"\nrealtime_priority = 0\n',
                      url)


def udp_listener() -> tuple[socket.socket, int]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    return sock, sock.getsockname()[1]


def drain(sock: socket.socket) -> list[bytes]:
    out = []
    while True:
        try:
            out.append(sock.recv(65536))
        except BlockingIOError:
            return out


SERVED_TRIGGER = ('[trigger]\nkind = "threshold"\nfraction = 0.2\nhysteresis = 0.1\nrefractory_s = 0.2\n'
                  'rearm_quiet_s = 0.05\n')
"""A trigger that fires at each press of ``press_cycles``."""


def served_daemon(work: Path, sinks: str = "stdout = false", stream=None, more: str = ""):
    """A Daemon serving a valid model (always ``pull``) for the SDH-2 layout, frames fed by the caller; its
    config is work/served.toml (a SIGHUP reads it again), ``sinks`` its [sinks] lines."""
    from benchmarks import hostile_models as H
    from firmware_io.layout import SensorLayout
    from runtime.config import load_config
    from runtime.daemon import Daemon
    from runtime.model import load_model

    models = work / "models"
    models.mkdir(parents=True, exist_ok=True)
    path = write_model(models, "good.onnx", H.valid(bias_class=0))
    config = sim_config(work / "served.toml", models, f"[sinks]\n{sinks}\n{SERVED_TRIGGER}{more}", "realtime_priority = 0\n")
    daemon = Daemon(load_config(config), stream=stream)
    daemon.serve(load_model(path), SensorLayout.sdh2())
    return daemon


def press_cycles(daemon, cycles: int, first: int = 0, level: int = 3000) -> int:
    """``cycles`` presses of a distal taxel (10 frames on, 10 off) through the hot path; the next frame number."""
    end = first + 20 * cycles
    for frame in pressed_frames(daemon.layout, range(first, end), lambda n: (n - first) % 20 < 10, level):
        daemon.handle_frame(frame)
    return end


class LogLines(logging.Handler):
    """The daemon's log lines (``handover.*``, warnings and up) while in a ``with`` block."""

    def __init__(self, level: int = logging.WARNING) -> None:
        super().__init__(level)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())

    def __enter__(self) -> list[str]:
        logger = logging.getLogger("handover")
        self._level = logger.level
        logger.addHandler(self)
        if logger.getEffectiveLevel() > self.level:
            logger.setLevel(self.level)
        return self.lines

    def __exit__(self, *exc) -> None:
        logger = logging.getLogger("handover")
        logger.removeHandler(self)
        logger.setLevel(self._level)


def in_thread(fn: Callable[[], object], guard_s: float = HANG_GUARD_S) -> tuple[bool, object]:
    """Run ``fn`` in a daemon thread: (finished, its result or exception). A part that blocks for
    good leaves the thread behind instead of the caller."""
    box: list = []

    def run() -> None:
        try:
            box.append(fn())
        except BaseException as exc:  # reported to the caller
            box.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(guard_s)
    return (not thread.is_alive()), (box[0] if box else None)


# -- 1, 2: stdout ----------------------------------------------------------------------------------
def blocked_stdout(work: Path) -> dict:
    """A daemon whose stdout is a pipe nobody reads keeps deciding; its UDP listener keeps receiving."""
    import fcntl

    listener, port = udp_listener()
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, SMALL_PIPE)
    stream = os.fdopen(write_end, "w", encoding="utf-8")
    daemon = served_daemon(work, f'stdout = true\nudp = ["127.0.0.1:{port}"]', stream=stream)
    try:
        finished, _ = in_thread(lambda: press_cycles(daemon, 60))
        received = len([d for d in drain(listener) if b'"decision"' in d])
        events = daemon.health.events
        stdout = daemon.sinks.sinks[0]
        waiting = len(getattr(stdout, "_backlog", b""))
        held = finished and events >= 50 and received == events
        detail = (f"{events} decisions reported with stdout never read; the UDP listener received {received}; "
                  f"stdout holds {waiting} bytes for its reader, dropped {getattr(stdout, 'dropped', 0)} lines"
                  if finished else f"the hot path blocked on stdout after {daemon.health.events} events")
        return {"held": held, "detail": detail, "events": events, "udp_received": received}
    finally:
        listener.close()
        os.close(read_end)


def blocked_stdout_process(work: Path) -> dict:
    """``handover run | nobody-reads``: UDP keeps receiving after the pipe is full; SIGTERM ends it (exit 0)."""
    import fcntl

    from benchmarks import hostile_models as H

    models, state = _daemon_folders(work)
    write_model(models, "good.onnx", H.valid(bias_class=0))
    listener, port = udp_listener()
    config = _run_config(state / "h.toml", "sim://?events=400&speed=16", models,
                         f'[sinks]\nudp = ["127.0.0.1:{port}"]\n'
                         '[trigger]\nkind = "threshold"\nfraction = 0.02\nhysteresis = 0.01\nrefractory_s = 0.3\n')
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, SMALL_PIPE)
    proc = spawn_daemon(config, stdout=write_end)
    os.close(write_end)
    try:
        got: list[bytes] = []
        deadline = time.monotonic() + 4 * HANG_GUARD_S
        while time.monotonic() < deadline and proc.poll() is None and len(got) < 60:
            got += [d for d in drain(listener) if b'"decision"' in d]
            time.sleep(0.1)
        pipe_full = len(os.read(read_end, 1 << 20)) >= SMALL_PIPE - 512  # read only now: it was full
        code = stop_daemon(proc, HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            proc.kill()
        err = proc.communicate()[1]
        listener.close()
        os.close(read_end)
    held = len(got) >= 60 and pipe_full and code == 0 and "Traceback" not in err
    return {"held": held, "udp_received": len(got), "exit_code": code,
            "detail": f"UDP received {len(got)} events while stdout (a {SMALL_PIPE}-byte pipe) was never read "
                      f"(full: {pipe_full}); SIGTERM: exit code {code}"}


def closed_stdout(work: Path) -> dict:
    """``handover run ... >&-``: one line (sinks.stdout) or no stdout sink, never a crash."""
    from benchmarks import hostile_models as H

    models, state = _daemon_folders(work)
    write_model(models, "good.onnx", H.valid(bias_class=0))
    listener, port = udp_listener()
    outcomes = {}
    for stdout_on in (True, False):
        config = _run_config(state / f"h-{stdout_on}.toml", "sim://?events=20&speed=16", models,
                             f'[sinks]\nstdout = {str(stdout_on).lower()}\nudp = ["127.0.0.1:{port}"]\n'
                             '[trigger]\nkind = "threshold"\nfraction = 0.02\nhysteresis = 0.01\n')
        proc = subprocess.Popen(["sh", "-c", 'exec "$0" -m runtime.cli run --config "$1" >&-', sys.executable,
                                 str(config)], cwd=ROOT, stderr=subprocess.PIPE, text=True)
        got = 0
        deadline = time.monotonic() + HANG_GUARD_S
        while time.monotonic() < deadline and proc.poll() is None and got < 1:
            got += len(drain(listener))
            time.sleep(0.1)
        code = stop_daemon(proc, HANG_GUARD_S)
        err = proc.communicate()[1]
        said = [line for line in err.splitlines() if "sinks.stdout" in line]
        outcomes[stdout_on] = {"exit_code": code, "udp_datagrams": got, "traceback": "Traceback" in err,
                               "stdout_lines": len(said)}
    listener.close()
    held = all(o["exit_code"] == 0 and not o["traceback"] and o["udp_datagrams"] > 0 for o in outcomes.values())
    held = held and outcomes[True]["stdout_lines"] <= 1 and outcomes[False]["stdout_lines"] == 0
    return {"held": held, "outcomes": {str(k): v for k, v in outcomes.items()},
            "detail": "; ".join(f"sinks.stdout = {str(k).lower()}: exit {v['exit_code']}, "
                                f"{v['udp_datagrams']} datagrams, {v['stdout_lines']} line(s) about stdout"
                                f"{', a traceback' if v['traceback'] else ''}" for k, v in outcomes.items())}


# -- 3: DNS ------------------------------------------------------------------------------------------
def silent_dns(work: Path) -> dict:
    """A UDP sink named by a host whose DNS does not answer: the daemon is built (READY) and reloads
    (SIGHUP) without waiting for it; events reach the host once it resolves; ``--check`` names it."""
    import runtime.name_resolver as R
    from runtime.sinks import UdpSink

    listener, port = udp_listener()
    answer = threading.Event()
    real = socket.getaddrinfo

    def dns(host, port, *args, **kw):  # a DNS server that answers only when told to
        if host == "robot-pc.example":
            answer.wait()
            return real("127.0.0.1", port, *args, **kw)
        return real(host, port, *args, **kw)

    original = socket.getaddrinfo
    socket.getaddrinfo = dns
    try:
        daemon = None

        def build():
            nonlocal daemon
            daemon = served_daemon(work, f'stdout = false\nudp = ["robot-pc.example:{port}"]')
            daemon.reload()  # SIGHUP: the sinks are built again
            return daemon

        built, _ = in_thread(build, guard_s=HANG_GUARD_S / 3)
        before = press_cycles(daemon, 3) if built else 0
        sink = next((s for s in daemon.sinks.sinks if isinstance(s, UdpSink)), None) if built else None
        unsent = sink.errors if sink is not None else 0
        answer.set()
        resolved = sink is not None and wait_until(lambda: sink.address is not None)
        if built and resolved:
            press_cycles(daemon, 3, first=before)
        got = len([d for d in drain(listener) if b'"decision"' in d])
    finally:
        socket.getaddrinfo = original
        answer.set()
        listener.close()
    check = R.resolve_problem("no-such-host.invalid", 9, bound_s=HANG_GUARD_S / 3)
    unresolvable = sim_config(work / "unresolvable.toml", work, '[sinks]\nudp = ["no-such-host.invalid:9999"]\n')
    done = cli(["run", "--config", str(unresolvable), "--check"])
    check_says = "no-such-host.invalid" in done.stderr and "sinks.udp" in done.stderr
    held = built and resolved and unsent == 3 and got == 3 and check is not None and check_says
    return {"held": held, "detail": f"built and reloaded while DNS was silent: {built}; {unsent} events counted "
                                    f"unsent before it answered, {got} received after; --check names the "
                                    f"unresolvable host: {check_says}"}


# -- 4, 6: the control socket, the ROS 2 grasp input ------------------------------------------------
SENDER = ("import socket, sys; s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM); a = sys.argv[1]\n"
          "try:\n    s.sendto(b'grasp open', a.encode().replace(b'@', b'\\0', 1) if a.startswith('@') else a)\n"
          "except OSError as e:\n    print(e.errno)")


def _send_as(uid: int | None, address: str) -> str:
    """``grasp open`` to ``address`` from a process of user ``uid`` (None: this user)."""
    python = "/usr/bin/python3" if Path("/usr/bin/python3").exists() else sys.executable
    done = subprocess.run([python, "-c", SENDER, address], capture_output=True, text=True, timeout=HANG_GUARD_S,
                          user=uid, cwd="/")
    return done.stdout.strip() or "sent"


def foreign_grasp(work: Path) -> dict:
    """``grasp open`` from another user, to an abstract and a filesystem control socket, is dropped and
    counted; from the daemon's user it is heard. The ROS 2 grasp input is off by default, and turned on
    without SROS2 it is not subscribed (also with LOCALHOST discovery: every local user), in one line."""
    from runtime.config import Ros2Config
    from runtime.ros2 import robot_inputs

    if os.geteuid() != 0:
        return {"held": False, "tried": False, "detail": "needs root to send as another user; not tried"}
    outcomes = {}
    for kind, address in (("abstract", f"@handover-hostile-{os.getpid()}"), ("path", str(work / "c.sock"))):
        daemon = served_daemon(work / kind, more=f'[control]\nsocket = "{address}"\n')
        daemon.start_control()
        control = daemon.control
        try:
            foreign = _send_as(NOBODY, address)  # "sent", or the errno the kernel refused it with
            if foreign == "sent":
                wait_until(lambda c=control: c.refused + c.received >= 1, HANG_GUARD_S / 3)
            heard_foreign = daemon.detector.grasp_request is not None
            _send_as(None, address)
            wait_until(lambda c=control: c.received >= 1, HANG_GUARD_S / 3)
            mode = oct(os.stat(address).st_mode & 0o777) if kind == "path" else "-"
            outcomes[kind] = {"foreign": foreign, "refused": control.refused, "heard_foreign": heard_foreign,
                              "own_heard": daemon.detector.grasp_request == (False, "control"), "mode": mode}
        finally:
            daemon.stop_control()
    listens, open_net = robot_inputs(Ros2Config(grasp=True), {"ROS_DOMAIN_ID": "7"})
    local = robot_inputs(Ros2Config(grasp=True), {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    held = (all(not o["heard_foreign"] and o["own_heard"] for o in outcomes.values())
            and outcomes["path"]["mode"] == "0o600" and not Ros2Config().grasp and open_net is not None
            and one_line(open_net, "ros2.grasp", "domain 7") and not listens and local[0] is False)
    return {"held": held, "tried": True, "outcomes": outcomes,
            "detail": "; ".join(f"{k}: from uid {NOBODY} {'heard' if o['heard_foreign'] else 'dropped'} "
                                f"({o['refused']} counted), own user heard: {o['own_heard']}, mode {o['mode']}"
                                for k, o in outcomes.items())
            + f"; ROS 2 grasp off by default: {not Ros2Config().grasp}; named when open to the network: "
              f"{open_net is not None}"}


def control_paths(work: Path) -> dict:
    """A control socket path that cannot work (a file, a folder, a symlink, too long, no parent):
    ``--check`` exits 2 with one line naming it, and the daemon refuses to start with the same line."""
    folder = work / "paths"
    folder.mkdir(parents=True)
    (folder / "file").write_text("x")
    (folder / "dir").mkdir()
    (folder / "link").symlink_to(folder / "elsewhere.sock")
    cases = {"regular file": folder / "file", "folder": folder / "dir", "symlink": folder / "link",
             "too long": folder / ("x" * 120 + ".sock"), "no parent": folder / "missing" / "c.sock"}
    models = work / "models"
    models.mkdir(parents=True, exist_ok=True)
    rows = {}
    for name, path in cases.items():
        config = sim_config(work / "c.toml", models, f'[control]\nsocket = "{path}"\n')
        done = cli(["run", "--config", str(config), "--check"])
        check_ok = done.returncode == 2 and one_line(done.stderr, "control.socket", str(path))
        daemon = served_daemon(work / "run" / name.replace(" ", "-"), more=f'[control]\nsocket = "{path}"\n')
        try:  # handover run exits 2 with this line
            daemon.start_control()
            said = ""
        except OSError as exc:
            said = str(exc)
        daemon.stop_control()
        run_ok = str(path) in said and "\n" not in said and daemon.control is None
        rows[name] = {"check_exit2_one_line": check_ok, "run_one_line": run_ok}
    held = all(r["check_exit2_one_line"] and r["run_one_line"] for r in rows.values())
    return {"held": held, "rows": rows,
            "detail": "; ".join(f"{k}: --check {'one line, exit 2' if r['check_exit2_one_line'] else 'PASSED IT'}, "
                                f"run {'one line' if r['run_one_line'] else 'FAILED'}" for k, r in rows.items())}


# -- 11: state files that cannot work ---------------------------------------------------------------
def state_file_paths(work: Path) -> dict:
    """``health_file`` / ``model.quarantine_file`` naming a folder (``/``, ``.``): one line at ``--check``,
    at ``run`` (exit 2) and at SIGHUP (the running config kept), never a crash."""
    models = work / "models"
    models.mkdir(parents=True, exist_ok=True)
    rows = {}
    for name, key, top, in_model in (("health_file = /", "health_file", 'health_file = "/"\n', ""),
                                     ("health_file = .", "health_file", 'health_file = "."\n', ""),
                                     ("quarantine_file = /", "model.quarantine_file", "", 'quarantine_file = "/"\n')):
        config = sim_config(work / "bad.toml", models, in_model, top)
        check = cli(["run", "--config", str(config), "--check"])
        run = cli(["run", "--config", str(config)], timeout=HANG_GUARD_S)
        daemon = served_daemon(work / "served")
        source = Path(daemon.cfg.source)
        source.write_text(top + source.read_text().replace("[model]\n", "[model]\n" + in_model))
        with LogLines() as said:
            daemon.reload()
        kept = daemon.cfg.health_file is None and daemon.cfg.model.quarantine_file is None
        reload_lines = [s for s in said if key in s]
        rows[name] = {"check": check.returncode == 2 and one_line(check.stderr, key),
                      "run": run.returncode == 2 and one_line(run.stderr, key) and "Traceback" not in run.stderr,
                      "sighup": kept and len(reload_lines) == 1}
    held = all(all(r.values()) for r in rows.values())
    return {"held": held, "rows": rows, "detail": "; ".join(
        f"{k}: " + ", ".join(f"{w} {'one line' if ok else 'FAILED'}" for w, ok in r.items()) for k, r in rows.items())}


# -- 12: SIGHUP with a config that is not whole -------------------------------------------------------
def partial_config(work: Path) -> dict:
    """SIGHUP while the config file is empty, cut off mid-line, or replaced by a FIFO: the running
    config is kept with one line and the loop never blocks; ``--check`` and ``run`` refuse the same."""
    rows = {}
    for name in ("empty", "cut mid-line", "FIFO"):
        daemon = served_daemon(work / name.replace(" ", "-"), more='[control]\nsocket = "@handover-kept"\n')
        source = Path(daemon.cfg.source)
        good, before = source.read_text(), daemon.cfg
        source.unlink()
        if name == "FIFO":
            os.mkfifo(source)
        else:
            source.write_text("" if name == "empty" else good[: good.index("[trigger]") + 12])
        with LogLines() as said:
            finished, _ = in_thread(daemon.reload, guard_s=HANG_GUARD_S / 3)
        kept = finished and daemon.cfg == before
        lines = [s for s in said if str(source) in s]
        check = cli(["run", "--config", str(source), "--check"], timeout=HANG_GUARD_S)
        run = cli(["run", "--config", str(source)], timeout=HANG_GUARD_S)
        rows[name] = {"sighup_kept_one_line": kept and len(lines) == 1,
                      "check_exit2_one_line": check.returncode == 2 and one_line(check.stderr, str(source)),
                      "run_exit2_one_line": run.returncode == 2 and one_line(run.stderr, str(source))}
        if name == "FIFO":
            source.unlink()
    held = all(all(r.values()) for r in rows.values())
    return {"held": held, "rows": rows, "detail": "; ".join(
        f"{k}: " + ", ".join(f"{w} {ok}" for w, ok in r.items()) for k, r in rows.items())}


# -- 13: crafted .dsa files ---------------------------------------------------------------------------
def _dsa(cells_x: object, cells_y: object, token: str, fullscale: str = "4095", width: str = "3.4",
         stamp: str = "1000") -> bytes:
    """A one-matrix, one-frame DSA-Konqueror file (plain XML) with the given header values."""
    return (f'<?xml version="1.0"?><root><sensor><matrix index="0"><cells_x>{cells_x}</cells_x>'
            f'<cells_y>{cells_y}</cells_y><texel_width>{width}</texel_width><fullscale>{fullscale}</fullscale>'
            f'</matrix></sensor><data><frame index="0"><time_stamp>{stamp}</time_stamp><frame_data>{token}'
            '</frame_data></frame></data></root>').encode()


def crafted_dsa_files(folder: Path) -> dict[str, Path]:
    import struct

    def run(n: float) -> str:  # a zero run of n taxels
        return struct.pack(">f", -float(n)).hex()

    five = struct.pack(">f", 5.0).hex() * 4
    files = {"65536x32768 matrix, one zero run": _dsa(65536, 32768, run(65536 * 32768)),
             "1e30 cells": _dsa(10**30, 1, run(1e30)), "fullscale = nan": _dsa(2, 2, five, fullscale="nan"),
             "fullscale = 1e400": _dsa(2, 2, five, fullscale="1e400"), "texel_width = 1e400": _dsa(2, 2, five, width="1e400"),
             "time stamp of 23 digits": _dsa(2, 2, five, stamp="9" * 23)}
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for i, (name, data) in enumerate(files.items()):
        out[name] = folder / f"crafted{i}.dsa"
        out[name].write_bytes(data)
    return out


READER = """import json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
from firmware_io.recordings.importers import import_any
from firmware_io.recordings.recording import RecordingError
out = {}
for path in sys.argv[1:]:
    try:
        import_any(path)
        out[path] = "accepted"
    except RecordingError as exc:
        out[path] = "one line" if str(exc).startswith(path) and "\\n" not in str(exc) else "unnamed: " + str(exc)
    except BaseException as exc:
        out[path] = type(exc).__name__ + ": " + str(exc)[:120]
print(json.dumps(out))
"""


def crafted_dsa(work: Path) -> dict:
    """Crafted .dsa files (a header declaring 65536 x 32768 taxels, a NaN full scale, numbers too big
    for any field): refused in one line naming the file, without allocating what the header asks
    (the reader runs with 2 GiB of address space), and ``handover import`` says the same."""
    files = crafted_dsa_files(work / "crafted")
    done = subprocess.run([sys.executable, "-c", READER, *map(str, files.values())], capture_output=True, text=True,
                          cwd=ROOT, timeout=4 * HANG_GUARD_S)
    try:
        outcome = json.loads(done.stdout)
    except ValueError:
        outcome = {}
    rows = {name: outcome.get(str(path), f"reader died: {done.stderr.strip()[-120:]}") for name, path in files.items()}
    imported = cli(["import", str(work / "crafted"), "--out", str(work / "imported")], timeout=4 * HANG_GUARD_S)
    unexpected = "unexpected" in imported.stderr or "Traceback" in imported.stderr
    held = all(v == "one line" for v in rows.values()) and not unexpected
    return {"held": held, "rows": rows,
            "detail": "; ".join(f"{k}: {v}" for k, v in rows.items()) + f"; handover import: "
                      f"{'an unexpected error' if unexpected else 'one line a file'}"}


# -- 8: what a model file claims ----------------------------------------------------------------------
def model_with(folder: Path, name: str, **meta) -> Path:
    """A valid model (always ``pull``) whose metadata says ``meta`` (same graph, another file)."""
    from benchmarks import hostile_models as H
    from trainer.measure import with_metadata

    folder.mkdir(parents=True, exist_ok=True)
    plain = write_model(folder, f".{name}.plain", H.valid(bias_class=0))
    out = with_metadata(plain, folder / f".{name}.tmp", lambda m: m.update(meta))
    plain.unlink()
    os.chmod(out, 0o644)
    os.replace(out, folder / name)
    return folder / name


def model_claims(work: Path) -> dict:
    """A model saying ``sample_rate_hz = 1`` on a 32 Hz stream: a decision later than the stream's period
    is a missed deadline (not one of a second), and the health line names the model's claim; a
    ``fullscale`` above the 12-bit pads' 4095 is refused with one line at load and at ``--check``."""
    from firmware_io.layout import SensorLayout
    from runtime.model import ModelContractError, load_model

    daemon = served_daemon(work / "rate")
    slow_claim = load_model(model_with(work / "claims", "one-hertz.onnx", sample_rate_hz=1.0))
    daemon.serve(slow_claim, SensorLayout.sdh2())
    # 32 Hz by the device's time stamps; each frame 50 ms old when handled; the first press after a block is measured
    for frame in pressed_frames(daemon.layout, range(200), lambda n: 30 <= n % 40 < 35, 3000, late_s=0.05):
        daemon.handle_frame(frame)
    h = daemon.health
    named = "sample_rate_hz" in h.last_error or any("sample_rate_hz" in e["error"] for e in h.errors)
    refused = {}
    for value in (1e15, 1e30):
        path = model_with(work / f"fullscale-{value:g}", "big.onnx", fullscale=value)
        try:
            load_model(path)
            refused[f"{value:g}"] = "accepted"
        except ModelContractError as exc:
            refused[f"{value:g}"] = "one line" if one_line(str(exc), str(path), "fullscale") else str(exc)[:100]
        config = sim_config(work / "fs.toml", path.parent)
        done = cli(["run", "--config", str(config), "--check", "--require-model"])
        if done.returncode != 1 or "fullscale" not in done.stderr:
            refused[f"{value:g}"] += "; --check did not name it"
    held = h.decisions > 0 and h.missed_deadlines == h.decisions and named and all(
        v == "one line" for v in refused.values())
    return {"held": held, "detail": f"sample_rate_hz = 1 on a 32 Hz stream: {h.missed_deadlines} of {h.decisions} "
                                    f"decisions 50 ms late counted missed; health names the claim: {named}; "
                                    + "; ".join(f"fullscale = {k}: {v}" for k, v in refused.items())}


# -- 9: what the folder holds is what is served ---------------------------------------------------------
def _settle(daemon) -> str | None:
    """Two polls (a file must look the same twice) and the loop's swap: the file that serves now."""
    for _ in range(2):
        daemon.models.watcher.poll()
    daemon._housekeeping(time.monotonic())
    return serving(daemon)


def _check_names(config: Path) -> str | None:
    done = cli(["run", "--config", str(config), "--check"])
    for name in ("old.onnx", "new.onnx", "a.onnx", "b.onnx"):
        if f"({name})" in done.stdout:
            return name
    return None


def folder_rollbacks(work: Path) -> dict:
    """A no-op ``chmod`` on an older model, removing the newest file, switching a symlinked folder:
    the daemon serves the file the folder now names, and ``--check`` names the same."""
    from benchmarks import hostile_models as H

    state = work / "state"
    state.mkdir(parents=True)
    rows = {}
    # chmod and removal
    models = work / "models"
    models.mkdir()
    write_model(models, "old.onnx", H.valid(bias_class=1, tag="old"), mtime=time.time() - 100)
    write_model(models, "new.onnx", H.valid(bias_class=2, tag="new"), mtime=time.time() - 50)
    daemon = folder_daemon(models, state / "status.json")
    config = sim_config(state / "h.toml", models)
    os.chmod(models / "old.onnx", 0o644)  # a no-op, that changes the ctime
    rows["chmod 644 on the older file"] = (_settle(daemon), _check_names(config), "new.onnx")
    (models / "new.onnx").unlink()
    rows["the newest file removed"] = (_settle(daemon), _check_names(config), "old.onnx")
    (models / "old.onnx").unlink()
    rows["every file removed"] = (_settle(daemon), _check_names(config), None)
    # a symlinked folder switched
    for name, tag, age in (("a", "a", 50), ("b", "b", 100)):
        (work / name).mkdir()
        write_model(work / name, f"{name}.onnx", H.valid(bias_class=3, tag=tag), mtime=time.time() - age)
    link = work / "current"
    link.symlink_to(work / "a")
    switched = folder_daemon(link, state / "status.json")
    sim_config(config, link)
    tmp_link = work / ".current.tmp"
    tmp_link.symlink_to(work / "b")
    os.replace(tmp_link, link)  # the atomic switch of a deploy tool
    rows["a symlinked folder switched to an older release"] = (_settle(switched), _check_names(config), "b.onnx")
    held = all(serving == check == want for serving, check, want in rows.values())
    return {"held": held, "rows": {k: {"serving": s, "check": c, "expected": w} for k, (s, c, w) in rows.items()},
            "detail": "; ".join(f"{k}: serves {s}, --check names {c} (expected {w})" for k, (s, c, w) in rows.items())}


# -- 7: a model that hangs on real windows --------------------------------------------------------------
def hanging_model(work: Path) -> dict:
    """A model that passes load and warm-up and runs a 2e9-step Loop on its first real window: the
    decision is ended from outside the hot thread, the model is out of service (the one it replaced
    serves) within two sample periods of that window, and stays out after a restart."""
    from benchmarks import hostile_models as H

    models, state = _daemon_folders(work)
    write_model(models, "old.onnx", H.valid(bias_class=1, tag="old"), mtime=time.time() - 100)
    write_model(models, "hang.onnx", H.hang(), mtime=time.time() - 10)
    settings = {"realtime_priority": 0, "trigger": {"kind": "threshold", "fraction": 0.2, "hysteresis": 0.1}}
    daemon = folder_daemon(models, state / "status.json", **settings)
    served_first = serving(daemon)
    daemon.guard.start()
    took = None
    try:
        for frame in pressed_frames(daemon.layout, range(40), lambda n: False, 0):  # the stream's period is measured
            daemon.handle_frame(frame)
        period = daemon.detector.frame_clock.deadline_s()
        frames = list(pressed_frames(daemon.layout, range(40, 80), lambda n: n < 60, int(H.SLEEPER_PEAK)))

        def feed() -> float | None:
            slowest = 0.0
            for frame in frames:
                t0 = time.perf_counter()
                daemon.handle_frame(frame)
                slowest = max(slowest, time.perf_counter() - t0)
            return slowest

        finished, took = in_thread(feed, guard_s=4 * HANG_GUARD_S)
    finally:
        daemon.guard.stop()
    daemon.models.watcher.poll(require_stable=False)  # the watcher's next poll: the newest file left serves
    daemon._housekeeping(time.monotonic())
    serves = serving(daemon)
    after_restart = serving(folder_daemon(models, state / "status.json", **settings))
    out = (finished and served_first == "hang.onnx" and daemon.guard.ended == 1 and serves == "old.onnx"
           and after_restart == "old.onnx" and daemon.health.models_quarantined == 1)
    in_time = isinstance(took, float) and took < 2 * period
    took_ms = f"{took * 1e3:.1f} ms" if isinstance(took, float) else "never"
    return {"held": out and in_time, "held_untimed": out, "took_ms": None if not isinstance(took, float) else took * 1e3,
            "detail": f"served first: {served_first}; its first real window took {took_ms} (two periods: "
                      f"{2 * period * 1e3:.1f} ms) until it was out of service; {daemon.guard.ended} decision(s) "
                      f"ended; serving then: {serves}; after a restart: {after_restart}"}


def hanging_model_process(work: Path) -> dict:
    """``handover run`` replaying real-looking frames into a model that hangs on them: the model is
    quarantined, the old one serves, SIGTERM ends the daemon (exit 0), and ``--check`` keeps it out."""
    from benchmarks import hostile_models as H
    from firmware_io.layout import SensorLayout
    from firmware_io.recordings.recording import Recording

    models, state = _daemon_folders(work)
    write_model(models, "old.onnx", H.valid(bias_class=1, tag="old"), mtime=time.time() - 100)
    write_model(models, "hang.onnx", H.hang(), mtime=time.time() - 10)
    layout = SensorLayout.sdh2()
    frames = np.zeros((320, layout.n_taxels), dtype=np.uint16)
    column = int(layout.columns("distal")[40])
    for start in (100, 220):
        frames[start:start + 20, column] = int(H.SLEEPER_PEAK)
    rec = Recording(layout, frames, np.arange(len(frames)) * NOMINAL_PERIOD_S, [], {"source": "hostile"})
    path = rec.save(work / "presses.hrec")
    config = _run_config(state / "h.toml", f"replay://{path}?speed=1&loop=1", models,
                         '[trigger]\nkind = "threshold"\nfraction = 0.2\nhysteresis = 0.1\n')
    proc = spawn_daemon(config, stdout=subprocess.PIPE)
    try:
        status = status_when(state / "status.json", proc, lambda s: s.get("models_quarantined", 0) >= 1
                             and s.get("events", 0) >= 1, 4 * HANG_GUARD_S)
        code = stop_daemon(proc, HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            proc.kill()
        out, err = proc.communicate()
    check = cli(["run", "--config", str(config), "--check"])
    models_said = [json.loads(line).get("model_file") for line in out.splitlines() if '"type":"model"' in line]
    held = (status.get("models_quarantined") == 1 and status.get("events", 0) >= 1 and code == 0
            and "(old.onnx)" in check.stdout and "hang.onnx" in check.stderr and "Traceback" not in err)
    return {"held": held, "exit_code": code, "detail": f"models announced {models_said}; quarantined "
            f"{status.get('models_quarantined')}, events after it {status.get('events')}; SIGTERM: exit {code}; "
            f"--check after it would serve old.onnx: {'(old.onnx)' in check.stdout}"}


# -- 10: a controller that comes back with another layout -------------------------------------------------
def layout_comes_back(work: Path) -> dict:
    """The controller reconnects reporting 3 pads, then 6 again: meanwhile the health file names the
    error; then the model that fits serves again, without SIGHUP or a new drop."""
    from benchmarks import hostile_models as H
    from firmware_io.layout import SensorLayout
    from runtime.config import config_from_dict
    from runtime.daemon import Daemon

    models, state = _daemon_folders(work)
    write_model(models, "six-pads.onnx", H.valid(bias_class=0))
    cfg = config_from_dict({"device": {"url": "sim://"}, "sinks": {"stdout": False}, "model": {"folder": str(models)},
                            "health_file": str(state / "status.json")})
    daemon = Daemon(cfg)
    six = SensorLayout.sdh2()
    three = SensorLayout(tuple(six.matrices[:3]))
    daemon.models.start()
    daemon.models.watcher.stop()
    steps = []
    for layout in (six, three, six):
        daemon._stream_began(layout)  # what the device link calls at each connect
        for _ in range(2):
            daemon.models.watcher.poll()
        daemon._housekeeping(time.monotonic())
        daemon.write_health()
        status = read_json(state / "status.json")
        steps.append((layout.n_matrices, status.get("model_id"), status.get("last_error", "")))
    held = (steps[0][1] is not None and steps[1][1] is None and "six-pads.onnx" in steps[1][2]
            and steps[2][1] == steps[0][1] and steps[2][2] == "")
    return {"held": held, "detail": "; ".join(f"{n} pads: serving {m or 'none'}, health error "
                                              f"{e[:60]!r}" for n, m, e in steps)}


# -- 5: two daemons on one ROS 2 namespace --------------------------------------------------------------
def two_daemons_one_namespace(work: Path) -> dict:
    """Two daemons publishing on one ``ros2.namespace``: each warns in one line and its health view says so."""
    from importlib.util import find_spec

    if find_spec("rclpy") is None:
        return {"held": False, "tried": False, "detail": "rclpy is not installed (the ros extra); not tried"}
    env = {"ROS_DOMAIN_ID": str(1 + os.getpid() % 100), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    daemons = []
    try:
        for name in ("a", "b"):
            daemons.append(served_daemon(work / name, "stdout = false\nros2 = true"))
        def each_saw_the_other() -> bool:
            for d in daemons:
                d.write_health()  # the node looks at the graph when it publishes the health view
            return all("another daemon on this namespace" in (d.health.last_error or "") for d in daemons)

        with LogLines() as said:
            told = wait_until(each_saw_the_other)
        lines = [s for s in said if "another daemon on this namespace" in s]
        in_health = all("another daemon on this namespace" in d.health.last_error for d in daemons)
    finally:
        for d in daemons:
            d.sinks.close()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    held = told and len(lines) == 2 and in_health
    return {"held": held, "tried": True, "detail": f"each daemon saw the other: {told}; warning lines: {len(lines)}; "
                                                   f"in both health views: {in_health}"}


# -- the cases, as ``./dev bench hostile`` counts them ----------------------------------------------------
# -- 14: the controller as SDHLibrary's client sees it -------------------------------------------------------
def controller_reset_behind_tcp(work: Path) -> dict:
    """The emulated DSACON32m over TCP: a threshold acts on the frames; a host leaving resets it (push off,
    a plain write lost, a persistent one kept as the default) and the next host's open waits out its boot."""
    from firmware_io.client import DSAClient
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.frame_source import load_source
    from firmware_io.emulator.server import TcpEmulatorServer

    emulator = DeviceEmulator(load_source("sim", seed=0, events=2), speed=1.0, boot_s=2.0, boot_query_s=1.5)
    with TcpEmulatorServer(emulator) as server:
        first = DSAClient(server.url)
        layout = first.open()
        for m in range(layout.n_matrices):
            first.set_threshold(m, 4095)
        first.set_sensitivity(0, 0.25, persistent=True)
        first.start()
        frame = first.read_frame(2.0)
        first.close()
        t0 = time.monotonic()
        second = DSAClient(server.url)
        second.open()
        waited = time.monotonic() - t0
        threshold, sensitivity = second.get_threshold(0), second.get_sensitivity(0).cur_sens
        second.close()
    silenced = frame is not None and not frame.values.any()
    held = silenced and threshold == 0 and abs(sensitivity - 0.25) < 1e-6 and waited >= 1.5
    return {"held": held, "detail": f"threshold 4095 silenced the frames: {silenced}; after the host left: threshold "
                                    f"{threshold}, sensitivity {sensitivity:.2f} (0.25 stored), open waited {waited:.1f} s"}


CASES: tuple[tuple[int, str, tuple[Callable[[Path], dict], ...]], ...] = (
    (1, "a stdout nobody reads", (blocked_stdout, blocked_stdout_process)),
    (2, "stdout closed at start", (closed_stdout,)),
    (3, "a UDP sink host whose DNS is silent", (silent_dns,)),
    (4, "grasp messages from another user or the network", (foreign_grasp,)),
    (5, "two daemons on one ROS 2 namespace", (two_daemons_one_namespace,)),
    (6, "a control socket path that cannot work", (control_paths,)),
    (7, "a model that hangs on real windows", (hanging_model, hanging_model_process)),
    (8, "model metadata the stream contradicts", (model_claims,)),
    (9, "rollbacks in the model folder", (folder_rollbacks,)),
    (10, "a controller back with another layout, then the original", (layout_comes_back,)),
    (11, "health_file / quarantine_file naming a folder", (state_file_paths,)),
    (12, "SIGHUP with an empty, cut or FIFO config", (partial_config,)),
    (13, "crafted .dsa files", (crafted_dsa,)),
    (14, "a controller reset behind TCP, tuned by its host", (controller_reset_behind_tcp,)),
    (15, "files that eat the machine: deflated .hrec, score bombs, malformed scripts, frame bomb", (files_that_eat,)),
    (16, "a full disk during record, a killed save's temp file", (full_disk_record,)),
    (17, "another user holds the control name first, loops on bind during a reload", (squatted_control_name,)),
    (18, "another user's device-lock folder; a device spelled otherwise", (squatted_lock_folder, device_spellings)),
    (19, "a health folder the daemon cannot write", (unwritable_health_folder,)),
    (20, "early heads that contradict the full model", (lying_early_heads,)),
)
"""The world's attacks: number, what, and the probes whose results all must hold."""


def attack_world(work: Path, say: Callable[[str], None] = lambda line: None) -> dict:
    """Every case of ``CASES``; a probe that raises has not held. Returns the rows and the counts."""
    import tempfile

    rows = []
    for number, title, probes in CASES:
        results = []
        for probe in probes:
            say(f"hostile: world case {number}: {probe.__name__} ...")
            with tempfile.TemporaryDirectory(prefix=f"case{number}-", dir=work) as tmp:
                t0 = time.perf_counter()
                try:
                    result = probe(Path(tmp))
                except Exception as exc:  # what is being counted
                    result = {"held": False, "detail": f"{type(exc).__name__}: {str(exc)[:200]}"}
                result["seconds"] = round(time.perf_counter() - t0, 1)
                result["probe"] = probe.__name__
            results.append(result)
        tried = all(r.get("tried", True) for r in results)
        rows.append({"case": number, "title": title, "tried": tried, "held": tried and all(r["held"] for r in results),
                     "probes": [{k: v for k, v in r.items() if k in ("probe", "held", "detail", "seconds", "took_ms")}
                                for r in results]})
    tried = [r for r in rows if r["tried"]]
    return {"cases": rows, "tried": len(tried), "held": sum(r["held"] for r in tried),
            "failures": sum(not r["held"] for r in tried)}
