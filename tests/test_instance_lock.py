"""One daemon per device and per health file: a second ``handover run`` on the same config exits 2
within seconds with one line naming the first one's pid, and the first one's health file never
changes hands. Real processes, real locks (the kernel drops them when the holder dies)."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from runtime import instance_lock

ROOT = Path(__file__).resolve().parents[1]


def _config(tmp_path: Path, url: str = "sim://?seed=0&events=4", health: str = "status.json") -> Path:
    models = tmp_path / "models"
    models.mkdir(exist_ok=True)
    cfg = tmp_path / f"handover-{health}.toml"
    cfg.write_text(f'log_level = "info"\nhealth_file = "{tmp_path / health}"\nrealtime_priority = 0\n'
                   f'[device]\nurl = "{url}"\n[model]\nfolder = "{models}"\npoll_interval_s = 0.2\n'
                   '[sinks]\nstdout = false\n')
    return cfg


def _env(tmp_path: Path) -> dict:
    env = dict(os.environ, XDG_RUNTIME_DIR=str(tmp_path / "run"), PYTHONPATH=str(ROOT))
    env.pop("RUNTIME_DIRECTORY", None)
    (tmp_path / "run").mkdir(exist_ok=True)
    return env


def _run(cfg: Path, env: dict, *more: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg), *more],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)


def _health(path: Path, timeout: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            time.sleep(0.1)
    raise AssertionError(f"no health file at {path}")


def test_a_second_daemon_on_the_same_config_exits_2_naming_the_first(tmp_path):
    cfg, env = _config(tmp_path), _env(tmp_path)
    health = tmp_path / "status.json"
    first = _run(cfg, env)
    try:
        _health(health)
        seen = []
        second = _run(cfg, env)
        while second.poll() is None:  # watch the first one's health file while the second one lives
            seen.append(_health(health)["uptime_s"])
            time.sleep(0.05)
        _, err = second.communicate()
        assert second.returncode == 2, err
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1 and f"pid {first.pid}" in lines[0] and "in use by another handover daemon" in lines[0], err
        for _ in range(15):  # and for a while after: uptime only grows (a second writer would restart it at 0)
            seen.append(_health(health)["uptime_s"])
            time.sleep(0.1)
        assert seen == sorted(seen) and seen[-1] > seen[0]
        check = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg), "--check"],
                               capture_output=True, text=True, env=env, cwd=ROOT, timeout=60)
        assert check.returncode == 0 and f"health_file {health} is in use by a running handover daemon (pid {first.pid}" \
            in check.stderr, check.stderr
        assert first.poll() is None
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=20)
    # the kernel released the locks with the process: the next daemon starts
    again = _run(cfg, env)
    try:
        time.sleep(0.5)
        _health(health)
        assert again.poll() is None
    finally:
        again.send_signal(signal.SIGTERM)
        again.communicate(timeout=20)


def test_a_second_daemon_on_the_same_device_with_its_own_health_file_is_refused(tmp_path):
    """The device lock alone: another health file, the same controller (a TCP emulator)."""
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.frame_source import load_source
    from firmware_io.emulator.server import TcpEmulatorServer

    env = _env(tmp_path)
    server = TcpEmulatorServer(DeviceEmulator(load_source("sim", seed=0, events=4))).start()
    first = _run(_config(tmp_path, server.url, "a.json"), env)
    try:
        _health(tmp_path / "a.json")
        t0 = time.monotonic()
        second = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config",
                                 str(_config(tmp_path, server.url, "b.json"))], capture_output=True, text=True,
                                env=env, cwd=ROOT, timeout=60)
        assert second.returncode == 2 and f"device {server.url} is in use" in second.stderr
        assert f"pid {first.pid}" in second.stderr and time.monotonic() - t0 < 30
        assert not (tmp_path / "b.json").exists()
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=20)
        server.stop()


def test_a_killed_holder_leaves_no_stale_lock_and_each_resource_counts_alone(tmp_path):
    env = _env(tmp_path)
    path = instance_lock.device_lock_path("tcp://127.0.0.1:13000", env)
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time\nfrom pathlib import Path\n"
                               "from runtime import instance_lock as L\n"
                               "L.take('device x', Path(sys.argv[1])); print('held', flush=True); time.sleep(60)",
                               str(path)], stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert f"pid {holder.pid}" in instance_lock.held_by_other("device x", path)
        with pytest.raises(instance_lock.InstanceLockError, match=f"pid {holder.pid}"):
            instance_lock.take("device x", path)
    finally:
        holder.kill()
        holder.wait()
    assert instance_lock.held_by_other("device x", path) is None  # SIGKILL: no clean-up ran, the kernel let go
    held = instance_lock.take("device x", path)
    instance_lock.release([held])
    # the same device with other read options is the same device; another health file on another device is free
    assert instance_lock.device_lock_path("tcp://127.0.0.1:13000?x=1", env) == path
    assert instance_lock.device_lock_path("tcp://127.0.0.1:13001", env) != path
    # a serial port by its real path: the udev symlink, the URL and the plain path are one device
    port = tmp_path / "ttyUSB0"
    port.touch()
    (tmp_path / "dsacon32m").symlink_to(port)
    same = {instance_lock.device_lock_path(u, env) for u in (f"serial://{tmp_path}/dsacon32m?baud=115200",
                                                             f"{tmp_path}/dsacon32m", f"serial://{port}")}
    assert len(same) == 1


def test_a_lock_name_planted_by_another_user_is_refused_and_what_it_leads_to_is_untouched(tmp_path):
    """The per-user temp folder can be made by anyone before the daemon's first start: a symbolic
    link or a second hard link at the lock's name must not have the daemon write its pid into the
    file it leads to."""
    env = _env(tmp_path)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    path = instance_lock.device_lock_path("tcp://127.0.0.1:13000", env)
    path.parent.mkdir(parents=True)
    path.symlink_to(victim)
    with pytest.raises(instance_lock.InstanceLockError, match="is a symbolic link: remove it"):
        instance_lock.take("device x", path)
    path.unlink()
    os.link(victim, path)
    with pytest.raises(instance_lock.InstanceLockError, match="not a lock file of its own: remove it"):
        instance_lock.take("device x", path)
    assert victim.read_text() == "precious\n"
    path.unlink()
    path.mkdir()
    with pytest.raises(instance_lock.InstanceLockError, match="is a folder: remove it"):
        instance_lock.take("device x", path)


def test_check_and_run_with_a_fifo_or_a_symlink_at_the_health_lock_say_one_line_and_never_hang(tmp_path):
    cfg, env = _config(tmp_path), _env(tmp_path)
    lock = instance_lock.health_lock_path(tmp_path / "status.json")
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    for plant in (lambda: os.mkfifo(lock), lambda: lock.symlink_to(victim)):
        plant()
        for more in (("--check",), ()):
            done = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--config", str(cfg), *more],
                                  capture_output=True, text=True, env=env, cwd=ROOT, timeout=60)
            lines = [line for line in done.stderr.splitlines() if line.strip()]
            assert done.returncode == 2 and len(lines) == 1 and f"lock of health_file {tmp_path / 'status.json'}" \
                in lines[0] and "remove it" in lines[0], (more, done.stderr)
        lock.unlink()
    assert victim.read_text() == "precious\n" and not (tmp_path / "status.json").exists()


def test_a_reload_onto_another_daemons_health_file_is_refused_and_a_reload_away_frees_the_old_one(tmp_path):
    """SIGHUP moves the locks with the config: onto a health file another daemon writes, the reload is
    refused in one line (both keep their own); onto a free one, the old one is let go at once."""
    env = _env(tmp_path)
    cfg_a, cfg_b = _config(tmp_path, health="a.json"), _config(tmp_path, health="b.json")
    a, b = _run(cfg_a, env), _run(cfg_b, env)
    try:
        _health(tmp_path / "a.json")
        _health(tmp_path / "b.json")
        cfg_a.write_text(cfg_a.read_text().replace("a.json", "b.json"))
        a.send_signal(signal.SIGHUP)
        deadline = time.monotonic() + 30
        while "reload refused" not in json.dumps(_health(tmp_path / "a.json")) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert "in use by another handover daemon" in json.dumps(_health(tmp_path / "a.json"))
        assert f"pid {b.pid}" in instance_lock.held_by_other("b", instance_lock.health_lock_path(tmp_path / "b.json"))
        cfg_a.write_text(cfg_a.read_text().replace("b.json", "c.json"))
        a.send_signal(signal.SIGHUP)
        _health(tmp_path / "c.json")
        while instance_lock.held_by_other("a", instance_lock.health_lock_path(tmp_path / "a.json")) \
                and time.monotonic() < deadline:
            time.sleep(0.2)
        assert instance_lock.held_by_other("a", instance_lock.health_lock_path(tmp_path / "a.json")) is None
        assert f"pid {a.pid}" in instance_lock.held_by_other("c", instance_lock.health_lock_path(tmp_path / "c.json"))
        assert a.poll() is None and b.poll() is None
    finally:
        for p in (a, b):
            p.send_signal(signal.SIGTERM)
        _, err = a.communicate(timeout=20)
        b.communicate(timeout=20)
    assert a.returncode == 0 and sum("SIGHUP" in line and "in use" in line for line in err.splitlines()) == 1, err


def test_one_lock_per_device_however_its_url_is_spelled(tmp_path):
    env = _env(tmp_path)
    spellings = ["tcp://127.0.0.1:13000", "tcp://localhost:13000", "TCP://127.0.0.1:13000", "tcp://127.1:13000",
                 "tcp://127.0.0.1", "tcp://[::ffff:127.0.0.1]:13000/", "tcp://0.0.0.0:13000", "tcp://0:13000"]
    assert len({instance_lock.device_lock_path(u, env) for u in spellings}) == 1
    assert instance_lock.device_lock_path("tcp://127.0.0.2:13000", env) != instance_lock.device_lock_path(
        spellings[0], env)


@pytest.mark.parametrize("planted", ["others_may_write", "symlink", "owned_by_another_user"])
def test_a_device_lock_folder_not_ours_alone_is_refused_and_nothing_is_written_there(tmp_path, planted):
    """Outside systemd the folder is $TMPDIR/handover-<uid>, which another user can make first: they
    held our lock (the daemon named 'pid 1', their text), or a symlink had root write its lock there."""
    if planted == "owned_by_another_user" and os.geteuid() != 0:
        pytest.skip("giving a folder to another user needs root")
    env = _env(tmp_path)
    path = instance_lock.device_lock_path("tcp://127.0.0.1:13000", env)
    theirs = tmp_path / "theirs"
    theirs.mkdir(mode=0o777)
    theirs.chmod(0o777)
    if planted == "symlink":
        path.parent.symlink_to(theirs)
    else:
        path.parent.mkdir()
        path.parent.chmod(0o777) if planted == "others_may_write" else os.chown(path.parent, 65534, 65534)
    why = {"others_may_write": "writable by others", "symlink": "is a symbolic link",
           "owned_by_another_user": "owned by uid 65534"}[planted]
    assert why in instance_lock.problem("device x", path)  # run --check says it (rc 2)
    with pytest.raises(instance_lock.InstanceLockError, match=f"lock folder {path.parent} .*{why}.*: remove it"):
        instance_lock.take("device x", path)
    assert not os.listdir(theirs) and not os.listdir(path.parent)


@pytest.mark.skipif(os.geteuid() != 0, reason="a lock file of another user needs root to make")
def test_a_lock_held_in_a_file_of_another_user_is_not_named_by_the_pid_they_wrote(tmp_path):
    path = tmp_path / ".status.json.lock"
    path.write_text("1\n")
    os.chown(path, 65534, 65534)
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, os, sys, time\nfd = os.open(sys.argv[1], os.O_RDONLY)\n"
                               "fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); time.sleep(60)", str(path)],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(instance_lock.InstanceLockError, match="a lock file of uid 65534") as caught:
            instance_lock.take("health_file x", path)
        assert "pid 1" not in str(caught.value)
        assert "pid 1" not in instance_lock.held_by_other("health_file x", path)
    finally:
        holder.kill()
        holder.wait()


def test_check_fails_on_a_health_folder_the_daemon_cannot_write(tmp_path):
    """--check said rc 0 and ``run`` exited 2 (cannot take the health file's lock): under systemd the
    service restarted in a loop. The check takes the lock as ``run`` would. Root writes anywhere, so the
    check runs in a child as uid 65534 (modules imported before, the clone may be private)."""
    from runtime.commands import daemon_cli
    from runtime.config import load_config

    cfg = load_config(_config(tmp_path))
    folder = tmp_path / "readonly"
    folder.mkdir(mode=0o555)
    cfg = dataclasses.replace(cfg, health_file=str(folder / "status.json"))
    read, write = os.pipe()
    child = os.fork()
    if child == 0:
        os.close(read)
        try:
            if os.geteuid() == 0:
                os.setgid(65534)
                os.setuid(65534)
            os.write(write, (daemon_cli._lock_problem(cfg) or "None").encode())
        finally:
            os._exit(0)
    os.close(write)
    with os.fdopen(read) as answer:
        line = answer.read()
    os.waitpid(child, 0)
    assert f"cannot take the lock of health_file {folder / 'status.json'}" in line and "writable" in line, line


def test_a_health_folder_the_daemon_cannot_write_is_refused_though_a_lock_file_there_is_writable(tmp_path):
    """A root folder (755) with a pre-made ``.status.json.lock`` of mode 666: as uid 65534 ``--check`` said
    0 and ``run`` went on logging "Permission denied", the health file never written (it is renamed into
    place, so the folder must be writable, not the lock)."""
    import shutil
    import tempfile

    from runtime.commands import daemon_cli
    from runtime.config import load_config

    if os.geteuid() != 0:
        pytest.skip("acting as another user needs root")
    cfg = load_config(_config(tmp_path))
    folder = Path(tempfile.mkdtemp(prefix="handover-roh-"))  # not under tmp_path: uid 65534 must reach it
    try:
        folder.chmod(0o755)
        lock = instance_lock.health_lock_path(folder / "status.json")
        lock.touch()
        lock.chmod(0o666)
        cfg = dataclasses.replace(cfg, health_file=str(folder / "status.json"))
        read, write = os.pipe()
        if (child := os.fork()) == 0:
            os.close(read)
            try:
                os.setgid(65534)
                os.setuid(65534)
                try:
                    instance_lock.Locks.take(cfg)
                    took = "taken"
                except instance_lock.InstanceLockError as exc:
                    took = str(exc)
                os.write(write, f"{daemon_cli._lock_problem(cfg)}\n{took}".encode())
            finally:
                os._exit(0)
        os.close(write)
        with os.fdopen(read) as answer:
            lines = answer.read().splitlines()
        os.waitpid(child, 0)
    finally:
        shutil.rmtree(folder)
    want = f"health_file {folder / 'status.json'}: its folder {folder} is not writable for uid 65534"
    assert len(lines) == 2 and all(line.startswith(want) for line in lines), lines
