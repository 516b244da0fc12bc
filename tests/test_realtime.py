"""The hot path's real-time scheduling (runtime/realtime.py): raised when permitted, a plain line
when not, and given back when the daemon stops."""

from __future__ import annotations

import os
import pwd
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from runtime import realtime
from runtime.config import ConfigError, config_from_dict
from runtime.daemon import Daemon
from runtime.listeners import FrameListener

pytestmark = pytest.mark.skipif(not hasattr(os, "SCHED_FIFO"), reason="SCHED_FIFO is Linux-only")
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


def _in_thread(fn):
    """Run ``fn`` in a fresh thread (scheduling is per thread: the test's own stays untouched)."""
    out: list = []
    t = threading.Thread(target=lambda: out.append(fn()))
    t.start()
    t.join(10)
    return out[0]


def test_zero_leaves_the_thread_alone():
    def run():
        before, line = realtime.enter_realtime(0)
        return before, realtime.current(), line

    before, after, line = _in_thread(run)
    assert before == after and after.policy == os.SCHED_OTHER
    assert "realtime_priority = 0" in line


@pytest.mark.skipif(not IS_ROOT, reason="raising a thread to SCHED_FIFO here needs root")
def test_raised_then_restored():
    def run():
        before, line = realtime.enter_realtime(20)
        raised = realtime.current()
        realtime.restore(before)
        return raised, realtime.current(), line

    raised, restored, line = _in_thread(run)
    assert raised == realtime.Scheduling(os.SCHED_FIFO, 20)
    assert restored.policy == os.SCHED_OTHER and "SCHED_FIFO 20" in line


_PROBE = """
import os, resource, sys
from runtime import realtime
limit = int(sys.argv[1])
try:
    resource.setrlimit(resource.RLIMIT_RTPRIO, (limit, limit))  # what systemd's LimitRTPRIO= does, then User=
except ValueError:  # a hard limit below it and no CAP_SYS_RESOURCE to raise it (some containers)
    print("cannot-set-limit"); sys.exit(0)
os.setgroups([]); os.setgid(int(sys.argv[3])); os.setuid(int(sys.argv[2]))
before, line = realtime.enter_realtime(realtime.DEFAULT_PRIORITY)
print(realtime.current().policy == os.SCHED_FIFO)
print(line)
"""


def _as_nobody(rtprio: int) -> list[str]:
    """A process that sets RLIMIT_RTPRIO and drops to ``nobody``, as systemd starts the service."""
    nobody = pwd.getpwnam("nobody")
    env = {"PYTHONPATH": os.getcwd(), "PATH": os.environ.get("PATH", "")}
    out = subprocess.run([sys.executable, "-c", _PROBE, str(rtprio), str(nobody.pw_uid), str(nobody.pw_gid)],
                         capture_output=True, text=True, timeout=60, env=env)
    assert out.returncode == 0, out.stderr
    return out.stdout.splitlines()


@pytest.mark.skipif(not IS_ROOT, reason="needs root to start a process as nobody")
def test_an_unprivileged_user_gets_one_line_and_normal_scheduling():
    raised, line = _as_nobody(0)
    assert raised == "False"
    assert "not permitted" in line and "LimitRTPRIO=" in line and "realtime_priority = 0" in line


@pytest.mark.skipif(not IS_ROOT, reason="needs root to start a process as nobody")
def test_the_units_rtprio_limit_is_enough_without_root():
    """What deploy/handover.service relies on: LimitRTPRIO= lets the unprivileged service user in."""
    lines = _as_nobody(realtime.DEFAULT_PRIORITY)
    if lines == ["cannot-set-limit"]:
        pytest.skip("this machine's hard RLIMIT_RTPRIO is below the unit's and cannot be raised (no CAP_SYS_RESOURCE)")
    raised, line = lines
    assert raised == "True" and f"SCHED_FIFO {realtime.DEFAULT_PRIORITY}" in line


def test_unit_allows_the_default_priority():
    unit = (Path(__file__).resolve().parents[1] / "deploy" / "handover.service").read_text()
    assert f"LimitRTPRIO={realtime.DEFAULT_PRIORITY}" in unit and "RestrictRealtime=no" in unit


@pytest.mark.parametrize("value", [-1, 100, 2.5, "high", True])
def test_config_bounds(value):
    with pytest.raises(ConfigError, match="realtime_priority"):
        config_from_dict({"realtime_priority": value})


@pytest.mark.skipif(not IS_ROOT, reason="raising a thread to SCHED_FIFO here needs root")
def test_daemon_decides_at_real_time_priority_and_gives_it_back():
    cfg = config_from_dict({"device": {"url": "sim://?events=2&realtime=0&loop=0"}, "sinks": {"stdout": False},
                            "realtime_priority": 7})
    seen: list = []

    class Probe(FrameListener):
        def on_frame(self, frame) -> None:
            seen.append(realtime.current())
            daemon.request_stop()

    daemon = Daemon(cfg)
    daemon.listeners.append(Probe())

    def run():
        daemon.run()
        return realtime.current()

    after = _in_thread(run)
    assert seen and seen[0] == realtime.Scheduling(os.SCHED_FIFO, 7)
    assert after.policy == os.SCHED_OTHER


@pytest.mark.skipif(not IS_ROOT, reason="raising a thread to SCHED_FIFO here needs root")
def test_nothing_started_from_the_hot_thread_inherits_it():
    """A busy child at the hot thread's priority would never give the core back."""
    import multiprocessing as mp

    def run():
        before, _ = realtime.enter_realtime(20)
        seen: list = []
        t = threading.Thread(target=lambda: seen.append(realtime.current()))
        t.start()
        t.join(5)
        ctx = mp.get_context("fork")
        parent, child = ctx.Pipe()
        p = ctx.Process(target=_report_scheduling, args=(child,))
        p.start()
        seen.append(parent.recv() if parent.poll(20) else None)
        p.join(5)
        realtime.restore(before)
        return seen

    thread_sched, child_sched = _in_thread(run)
    assert thread_sched.policy == os.SCHED_OTHER and child_sched == os.SCHED_OTHER


def _report_scheduling(pipe) -> None:
    pipe.send(os.sched_getscheduler(0))


@pytest.mark.skipif(not IS_ROOT, reason="raising a thread to SCHED_FIFO here needs root")
def test_a_device_that_sends_only_garbage_never_gets_real_time_priority():
    """Parsing a flood of nonsense at real-time priority would starve the PC: priority comes with
    the first valid frame of a link and goes with the link."""
    import socket
    import time

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    stop = threading.Event()

    server.settimeout(0.2)

    def flood() -> None:  # every connection gets nonsense (a connect that reads it fails and retries)
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            with conn:
                while not stop.is_set():
                    try:
                        conn.sendall(os.urandom(4096))
                    except OSError:
                        break
                    time.sleep(0.001)

    threading.Thread(target=flood, daemon=True).start()
    cfg = config_from_dict({"device": {"url": f"tcp://127.0.0.1:{server.getsockname()[1]}", "stall_timeout_s": 5.0},
                            "sinks": {"stdout": False}, "realtime_priority": 9})
    daemon = Daemon(cfg)
    tid: list[int] = []
    runner = threading.Thread(target=lambda: (tid.append(threading.get_native_id()), daemon.run()))
    runner.start()
    seen = []
    h = daemon.health
    def reached() -> bool:  # random bytes rarely hold a packet header: dropped bytes count too
        dropped = (getattr(daemon.link.client, "stats", None) or {}).get("bytes_dropped", 0)
        return h.protocol_errors + h.crc_errors + h.device_faults + dropped > 0

    deadline = time.monotonic() + 20.0  # connecting reads the nonsense first (up to its time bound)
    while time.monotonic() < deadline and (len(seen) < 20 or not reached()):
        time.sleep(0.1)
        if tid:
            seen.append(os.sched_getscheduler(tid[0]) & ~os.SCHED_RESET_ON_FORK)
    daemon.request_stop()
    stop.set()
    runner.join(10)
    server.close()
    assert seen and all(policy == os.SCHED_OTHER for policy in seen)
    assert h.frames_received == 0 and reached(), "the flood did not reach it"
