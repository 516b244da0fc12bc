"""Local users against the daemon (issue 40: N1, N3, N7, N8, N11), as cases of the hostile world.

Another user is uid 65534, acting through the system interpreter (the stdlib is all it needs; a
private clone's .venv is out of its reach); acting as them needs root, else a case is not tried.
Each case returns ``{"held": bool, "tried": bool, "detail": str}`` like the world's others.
"""

from __future__ import annotations

import os
import socket
import subprocess
import time
from pathlib import Path

from benchmarks.hostile_parts import HANG_GUARD_S, NOBODY, cli, one_line, sim_config, wait_until
from trainer.bench.harness import spawn_daemon, stop_daemon

__all__ = ["device_spellings", "lying_early_heads", "squatted_control_name", "squatted_lock_folder",
           "unwritable_health_folder"]
SQUAT = ("import socket, sys, time\ns = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)\n"
         "s.bind(b'\\0' + sys.argv[1][1:].encode()); print('bound', flush=True); time.sleep(60)")
LOOP = ("import socket, sys\nname = b'\\0' + sys.argv[1][1:].encode()\nwhile True:\n"
        "    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)\n    try:\n        s.bind(name)\n"
        "        print('won', flush=True)\n        break\n    except OSError:\n        s.close()\n")
NOT_ROOT = {"held": False, "tried": False, "detail": "needs root to act as another user; not tried"}


def _as_nobody(code: str, *args: str) -> subprocess.Popen:
    python = "/usr/bin/python3" if Path("/usr/bin/python3").exists() else "python3"
    return subprocess.Popen([python, "-c", code, *args], stdout=subprocess.PIPE, text=True, user=NOBODY,
                            group=NOBODY, extra_groups=[], cwd="/")


def _config(path: Path, rest: str, url: str = "sim://") -> Path:
    models = path.parent / "models"
    models.mkdir(parents=True, exist_ok=True)
    return sim_config(path, models, f"[sinks]\nstdout = false\n{rest}", "realtime_priority = 0\n", url)


def squatted_control_name(work: Path) -> dict:
    """N1: another user binds the daemon's abstract control name first: ``--check`` and ``run`` exit 2
    in one line, as for a socket path in a folder of theirs; a SIGHUP that changes ``[control]`` never lets
    go of the name while that user loops on bind (it won 5 of 5 times)."""
    from runtime.config import load_config
    from runtime.daemon import Daemon

    if os.geteuid() != 0:
        return NOT_ROOT
    address = f"@handover-squat-{os.getpid()}"
    config = _config(work / "c.toml", f'[control]\nsocket = "{address}"\n')
    squatter = _as_nobody(SQUAT, address)
    try:
        squatter.stdout.readline()
        check = cli(["run", "--config", str(config), "--check"])
        run = cli(["run", "--config", str(config)], timeout=HANG_GUARD_S)
    finally:
        squatter.kill()
        squatter.wait()
    refused = [p.returncode == 2 and one_line(p.stderr, address, "in use by another process") for p in (check, run)]
    theirs = work / "theirs"
    theirs.mkdir()
    os.chown(theirs, NOBODY, NOBODY)  # a path socket there: they could unlink it and bind their own
    path = _config(work / "path" / "c.toml", f'[control]\nsocket = "{theirs / "ctl.sock"}"\n')
    refused += [p.returncode == 2 and one_line(p.stderr, f"folder {theirs} is owned by uid {NOBODY}")
                for p in (cli(["run", "--config", str(path), *more], timeout=HANG_GUARD_S) for more in (["--check"], []))]
    settle = _config(work / "reload" / "c.toml", f'[control]\nsocket = "{address}"\narm_settle_s = 0.5\n')
    daemon = Daemon(load_config(settle))
    daemon.start_control()
    looper = _as_nobody(LOOP, address)
    try:
        time.sleep(0.3)
        _config(settle, f'[control]\nsocket = "{address}"\narm_settle_s = 1.0\n')
        for _ in range(5):
            daemon.reload()
        time.sleep(0.3)
        won = looper.poll() is not None
        applied = daemon.cfg.control.arm_settle_s == 1.0 and daemon.control is not None
    finally:
        looper.kill()
        looper.wait()
        daemon.stop_control()
        daemon.sinks.close()
    held = all(refused) and not won and applied
    return {"held": held, "tried": True,
            "detail": f"--check exit 2 in one line: {refused[0]}; run exit 2 in one line: {refused[1]}; a socket path "
                      f"in a folder of theirs: both exit 2 in one line: {refused[2] and refused[3]}; "
                      f"5 reloads under a uid {NOBODY} bind loop: name won by it: {won}, reload applied: {applied}"}


def squatted_lock_folder(work: Path) -> dict:
    """N3: outside systemd another user made ``$TMPDIR/handover-<uid>`` first (a folder of theirs, with a
    'pid 1' lock, or a symlink to it): ``--check`` and ``run`` refuse it in one line, name no pid of
    theirs and write nothing there."""
    if os.geteuid() != 0:
        return NOT_ROOT
    rows = {}
    for kind in ("their folder", "a symlink to their folder"):
        tmp = work / kind.replace(" ", "-")
        tmp.mkdir(mode=0o1777)
        theirs = tmp / "theirs"
        theirs.mkdir(mode=0o777)
        (theirs / "planted").write_text("1\n")
        for p in (theirs, theirs / "planted"):
            os.chown(p, NOBODY, NOBODY)
        folder = tmp / f"handover-{os.getuid()}"
        folder.symlink_to(theirs) if kind.startswith("a symlink") else theirs.rename(folder)
        env = {k: v for k, v in os.environ.items() if k not in ("XDG_RUNTIME_DIR", "RUNTIME_DIRECTORY")}
        env["TMPDIR"] = str(tmp)
        config = _config(tmp / "c.toml", "", url="tcp://127.0.0.1:9")
        done = [cli(["run", "--config", str(config), *more], timeout=HANG_GUARD_S, env=env)
                for more in (["--check"], [])]
        looked = folder if folder.is_dir() and not folder.is_symlink() else theirs
        rows[kind] = all(d.returncode == 2 and one_line(d.stderr, "lock folder", "remove it") and "pid 1" not in d.stderr
                         for d in done) and sorted(os.listdir(looked)) == ["planted"]
    return {"held": all(rows.values()), "tried": True,
            "detail": "; ".join(f"{k}: {'refused in one line, nothing written' if v else 'NOT REFUSED'}"
                                for k, v in rows.items())}


def device_spellings(work: Path) -> dict:
    """N8: a daemon on ``tcp://127.0.0.1:P``; a second one on ``tcp://localhost:P``, ``TCP://127.0.0.1:P``
    ``tcp://127.1:P``, ``tcp://0.0.0.0:P`` or ``tcp://0:P`` (each with its own health file) exits 2 naming the device."""
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()  # nothing listens: the first daemon retries the absent device and holds its lock
    env = dict(os.environ, XDG_RUNTIME_DIR=str(work / "run"))
    (work / "run").mkdir()
    config = _config(work / "a" / "c.toml", "", url=f"tcp://127.0.0.1:{port}")
    first = spawn_daemon(config, env, stderr=subprocess.DEVNULL)
    rows = {}
    try:
        from runtime import instance_lock

        lock = instance_lock.device_lock_path(f"tcp://127.0.0.1:{port}", env)
        wait_until(lambda: instance_lock.held_by_other("device", lock))
        for i, url in enumerate((f"tcp://localhost:{port}", f"TCP://127.0.0.1:{port}", f"tcp://127.1:{port}",
                                 f"tcp://0.0.0.0:{port}", f"tcp://0:{port}")):
            config = _config(work / f"b{i}" / "c.toml", "", url=url)
            done = cli(["run", "--config", str(config)], timeout=HANG_GUARD_S, env=env)
            rows[url] = done.returncode == 2 and one_line(done.stderr, "in use by another handover daemon")
    finally:
        stop_daemon(first, HANG_GUARD_S)
    return {"held": all(rows.values()), "tried": True,
            "detail": "; ".join(f"{u}: {'refused' if ok else 'RAN BESIDE IT'}" for u, ok in rows.items())}


def unwritable_health_folder(work: Path) -> dict:
    """N7: a health file in a folder the daemon cannot write (/sys refuses even root): ``--check`` exits 2
    in one line, as ``run`` does, so systemd's ExecStartPre stops a restart loop."""
    config = _config(work / "c.toml", "").read_text()
    (work / "c.toml").write_text('health_file = "/sys/handover-status.json"\n' + config)
    done = [cli(["run", "--config", str(work / "c.toml"), *more], timeout=HANG_GUARD_S) for more in (["--check"], [])]
    ok = [d.returncode == 2 and one_line(d.stderr, "health_file /sys/handover-status.json") for d in done]
    return {"held": all(ok), "tried": True, "detail": f"--check exit 2 in one line: {ok[0]}; run: {ok[1]}"}


def lying_early_heads(work: Path) -> dict:
    """N11: early heads that always say bump with certainty, against a full model that says pull, are
    disabled at warm-up with a note: the full model decides every event."""
    import json

    import onnx
    from onnx import TensorProto, helper

    from benchmarks import hostile_models as H
    from runtime.model import load_model

    proto = onnx.load_from_string(H.valid(bias_class=0))
    meta = json.loads(proto.metadata_props[0].value)
    n = len(meta["classes"])
    bump = meta["classes"].index("bump")
    proto.graph.initializer.append(helper.make_tensor("certain", TensorProto.FLOAT, [n],
                                                      [100.0 if i == bump else 0.0 for i in range(n)]))
    for p in (4, 8):
        proto.graph.node.extend([helper.make_node("Add", ["scores", "certain"], [f"scores_at_{p}"]),
                                 helper.make_node("ArgMax", [f"scores_at_{p}"], [f"label_at_{p}"], axis=1, keepdims=0)])
        proto.graph.output.extend([helper.make_tensor_value_info(f"label_at_{p}", TensorProto.INT64, ["N"]),
                                   helper.make_tensor_value_info(f"scores_at_{p}", TensorProto.FLOAT, ["N", n])])
    meta["early"] = {"points": [4, 8], "calibration": [[1.0, 0.0]] * 2, "threshold": 0.9, "agree": False}
    del proto.metadata_props[:]
    helper.set_model_props(proto, {"handover": json.dumps(meta)})
    path = work / "lying.onnx"
    path.write_bytes(proto.SerializeToString())
    model = load_model(path)
    held = model.early is None and bool(model.early_note) and "disabled" in model.early_note
    return {"held": held, "tried": True,
            "detail": f"heads served: {model.early.points if model.early else 'none'}; note: {model.early_note}"}
