"""``./dev bench soak --hours H``: the daemon for H hours at 32 Hz against the emulator, with
faults of every kind injected on a schedule, model swaps (good, broken and a rollback) and SIGHUP
reloads; writes ``results/soak.json`` and ``.md``.

The daemon is ``handover run`` in its own process (``benchmarks.soak_daemon`` adds only a log
of the frames it handled); the emulator serves the simulated hand's session (synthetic data) in a
loop over TCP. One fault at a time: the next waits until the daemon recovered from the last and
then streamed clean for a while (benchmarks/soak_schedule.py). Accounting (a handled frame is the
last one sent with its device stamp before it arrived: every TCP drop power-cycles the emulated
controller, whose clock restarts, so stamps recur):

- a frame is lost when the emulator sent it and the daemon never handled it; it counts as lost
  *inside* an injected fault when it was sent between the fault's start (less 0.25 s) and the
  first frame the daemon handled after the fault ended (plus 0.25 s); every other loss is
  ``frames_lost_outside_injected_faults`` (goal 0).
- an event is expected where the fault-free reference (the same recording through the same
  daemon code, in this process) decided one and the daemon handled every frame of the 4 s up to
  it outside any fault; ``events_lost`` counts expected events no UDP datagram reported (goal 0).
- ``watchdog_would_fire``: intervals longer than WatchdogSec without a WATCHDOG=1 ping; the
  schedule includes hangs (SIGSTOP for longer than WatchdogSec), which must each be caught, and
  nothing else may be.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import soak_rig
from benchmarks.soak_schedule import CLEAN_HISTORY_S, Fault, Plan, Schedule
from firmware_io.frame_timing import NOMINAL_RATE_HZ, nominal_stamp_ms
from trainer.bench import harness
from trainer.measure import load_average, load_note, machine_info, train_default_model, write_results

NAME = "soak"
WATCHDOG_S = 10.0
"""deploy/handover.service's WatchdogSec."""
STALL_TIMEOUT_S = 2.0


def _config_text(url: str, models: Path, udp_port: int, health: Path, log_level: str) -> str:
    return (f'log_level = "{log_level}"\nhealth_file = "{health}"\n\n[device]\nurl = "{url}"\n'
            f'stall_timeout_s = {STALL_TIMEOUT_S}\nreconnect_min_s = 0.2\nreconnect_max_s = 2.0\n\n'
            f'[scene]\npads = "all"\nevents = ["pull", "push", "hold", "bump"]\n\n'
            f'[model]\nfolder = "{models}"\npoll_interval_s = 1.0\n\n'
            f'[trigger]\nfraction = 0.05\nhysteresis = 0.02\n\n[sinks]\nstdout = false\nudp = ["127.0.0.1:{udp_port}"]\n')


def reference_events(model_path: Path, recording, config_text: str, loops: int = 3) -> set[int]:
    """Recording indices of the frames that end a decided window in steady state (fault-free)."""
    import tomllib

    from firmware_io.client import Frame
    from runtime.config import config_from_dict
    from runtime.detector import Detector
    from runtime.model import load_model

    data = tomllib.loads(config_text)
    data.pop("health_file", None)
    data["sinks"] = {"stdout": False}
    cfg = config_from_dict(data)
    ends: list[int] = []
    detector = Detector.from_config(cfg)
    detector.swap(load_model(model_path), recording.layout)
    n = recording.n_frames
    for k in range(loops * n):
        decision = detector.feed(Frame(k, nominal_stamp_ms(k), time.perf_counter(), recording.frames[k % n]))
        if decision is not None and decision.cls is not None:
            ends.append(decision.frame.number)
    return {f % n for f in ends if f >= n}  # the first loop warms the trigger up


class Soak:
    """One soak run: set up, drive the schedule, account."""

    def __init__(self, args, work: Path) -> None:
        from firmware_io.emulator.frame_source import load_source

        self.args, self.work, self.say = args, work, args.say
        self.plan = Plan.for_hours(args.hours)
        self.recording = load_source("sim", seed=args.seed, events=40)
        self.models = work / "models"
        self.models.mkdir()
        self.faults: list[Fault] = []
        self.swaps: list[dict] = []
        self.reloads: list[dict] = []
        self.rss: list[tuple[float, float]] = []

    # -- set-up -------------------------------------------------------------------------------
    def prepare_models(self) -> None:
        self.say("soak: training two default models on the simulated protocol (synthetic) ...")
        self.model_a = train_default_model(self.work, seed=self.args.seed, quick=True, name="a.onnx")
        self.model_b = train_default_model(self.work, seed=self.args.seed + 1, quick=True, name="b.onnx")
        from runtime.model import load_model

        self.ids = {"a": load_model(self.model_a).model_id, "b": load_model(self.model_b).model_id}
        harness.install_model(self.model_a, self.models, "a.onnx")
        self.expected_model = self.ids["a"]
        old = time.time() - 86400
        os.utime(self.models / "a.onnx", (old, old))  # a's mtime is older than b's will ever be
        self.good = [(self.models / "a.onnx", "a")]
        """The valid files in the folder (path, model), oldest first: the last serves."""

    def start(self) -> None:
        self.emulator = soak_rig.ScheduledEmulator(self.recording, speed=1.0, loop=True, seed=self.args.seed)
        self.server = soak_rig.serve(self.emulator)
        self.listener = harness.UdpListener()
        self.health = self.work / "status.json"
        self.config = self.work / "handover.toml"
        self.log_level = "info"
        self.config.write_text(self._config(self.log_level))
        self.notify = soak_rig.NotifyListener(str(self.work / "notify.sock"))
        self.frame_log = self.work / "frames.bin"
        env = {**os.environ, "PYTHONPATH": str(harness.ROOT), "NOTIFY_SOCKET": self.notify.path,
               "WATCHDOG_USEC": str(int(WATCHDOG_S * 1e6))}
        self.stderr_path = self.work / "daemon.log"
        self.stderr = open(self.stderr_path, "w")  # noqa: SIM115 - closed in finish()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.soak_daemon", "--frame-log", str(self.frame_log),
             "run", "--config", str(self.config)], cwd=str(harness.ROOT), env=env,
            stdout=subprocess.DEVNULL, stderr=self.stderr)
        deadline = time.monotonic() + 60
        while self.notify.counts["READY=1"] == 0 and time.monotonic() < deadline and self.proc.poll() is None:
            time.sleep(0.05)
        if self.notify.counts["READY=1"] == 0:
            raise RuntimeError(f"the daemon did not become ready (log: {self.stderr_path.read_text()[-400:]})")
        self.t0 = time.monotonic()

    def _config(self, log_level: str) -> str:
        return _config_text(self.server.url, self.models, self.listener.port, self.health, log_level)

    # -- the schedule ---------------------------------------------------------------------------
    def run_schedule(self) -> None:
        """Drive the schedule (benchmarks/soak_schedule.py) until the run's end, following the frames
        the daemon handles (a fault waits for the one before it to be over)."""
        from benchmarks.soak_daemon import FrameLogTail

        p, schedule, tail = self.plan, Schedule(self.plan, t0=self.t0), FrameLogTail(self.frame_log)
        last_say = 0.0
        while (t := time.monotonic() - self.t0) < p.seconds:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the daemon exited ({self.proc.returncode}): {self.stderr_path.read_text()[-400:]}")
            if t >= 10.0 * len(self.rss):
                self.rss.append((t, soak_rig.rss_mb(self.proc.pid) or float("nan")))
            self._follow(tail, schedule)
            action, what = schedule.due() or ("", "")
            if action == "fault":
                schedule.injected(self.inject(what))
            elif action == "swap":
                self.swap(what)
            elif action == "reload":
                self.reload()
            self.check_swaps()
            if t - last_say >= 300:
                last_say = t
                self.say(f"soak: {t / 60:.0f} of {p.seconds / 60:.0f} min, {len(self.faults)} faults, "
                         f"{len(self.swaps)} swaps, {len(self.listener.events)} events")
            time.sleep(0.2)

    def _follow(self, tail, schedule: Schedule) -> None:
        """Tell the schedule which frames the daemon handled since the last look (which were sent
        when: the last minute of the send log is enough, a frame arrives seconds after it is sent)."""
        from benchmarks.soak_account import which_sent

        stamps, times = tail.read()
        if not stamps:
            return
        sent = self.emulator.sent
        lo = max(0, len(sent) - int(60 * NOMINAL_RATE_HZ))
        recent = sent[lo:]
        for k, arrival in sorted(which_sent(recent, stamps, times).items()):
            schedule.handled(recent[k][1], arrival)

    def inject(self, kind: str) -> Fault:
        """Start fault ``kind``; a burst or a hang returns once it is over, the others at once."""
        emu, now = self.emulator, time.monotonic()
        fault = Fault(kind, now)
        if kind == "disconnect":
            emu.unplug()
            fault.end = now
        elif kind == "stall_short":
            emu.stall_for(0.5, now)
            fault.end = now + 0.5
        elif kind == "stall_long":
            emu.stall_for(STALL_TIMEOUT_S + 1.0, now)
            fault.end = now + STALL_TIMEOUT_S + 1.0
        elif kind in ("crc", "garbage_burst", "drop"):
            emu.burst({"garbage_burst": "garbage"}.get(kind, kind), 8)
            while emu.burst_active() and time.monotonic() - now < 5:
                time.sleep(0.02)
            fault.end = time.monotonic()
        elif kind == "garbage_stream":
            emu.stream_garbage(15.0, now)
            fault.end = now + 15.0
        elif kind == "hang":
            hang_s = WATCHDOG_S + 2.0
            os.kill(self.proc.pid, signal.SIGSTOP)
            time.sleep(hang_s)
            os.kill(self.proc.pid, signal.SIGCONT)
            fault.end = time.monotonic()
            fault.detail["stopped_s"] = hang_s
        self.faults.append(fault)
        return fault

    def swap(self, what: str) -> None:
        """Drop a file the documented way (temp name, rename), or a broken one, or roll back as
        docs/GUIDE.md says: remove the newest file (the newest valid file left serves)."""
        now = time.monotonic()
        name = f"{len(self.swaps):03d}-{what}.onnx"
        expect = None
        if what in ("good_a", "good_b"):
            harness.install_model(self.model_a if what == "good_a" else self.model_b, self.models, name)
            self.good.append((self.models / name, what[-1]))
            expect = self.ids[what[-1]]
        elif what == "rollback" and len(self.good) > 1:
            os.remove(self.good.pop()[0])
            expect = self.ids[self.good[-1][1]]
        else:
            data = self.model_b.read_bytes()
            body = {"truncated": data[: len(data) // 2], "random_bytes": os.urandom(len(data)), "empty": b"",
                    "world_writable": data}[what]
            tmp = self.models / f".{name}.tmp"
            tmp.write_bytes(body)
            os.chmod(tmp, 0o666 if what == "world_writable" else 0o644)
            os.replace(tmp, self.models / name)
        if expect is not None:
            self.expected_model = expect
        self.swaps.append({"t": round(now - self.t0, 1), "what": what, "expect": self.expected_model, "at": now,
                           "ok": None})

    def check_swaps(self) -> None:
        """A drop is right once the status file shows the model expected (a broken file: the model in
        use), checked for 30 s (a drop during a reconnect waits for it)."""
        pending = [s for s in self.swaps if s["ok"] is None]
        if not pending:
            return
        status = self._status()
        for s in pending:
            if status.get("model_id") == s["expect"] and time.monotonic() - s["at"] >= 3.0:
                s["ok"] = True
            elif time.monotonic() - s["at"] > 30.0:
                s["ok"], s["serving"] = False, status.get("model_id")

    def reload(self) -> None:
        self.log_level = "warning" if self.log_level == "info" else "info"
        self.config.write_text(self._config(self.log_level))
        before = self.notify.counts["RELOADING=1"]
        os.kill(self.proc.pid, signal.SIGHUP)
        self.reloads.append({"t": round(time.monotonic() - self.t0, 1), "before": before})

    def _status(self) -> dict:
        try:
            return json.loads(self.health.read_text())
        except (OSError, ValueError):
            return {}

    def finish(self) -> None:
        self.t_end = time.monotonic()
        time.sleep(1.0)  # the last datagrams
        self.final_status = self._status()
        harness.stop_daemon(self.proc, timeout=10)
        self.stderr.close()
        self.server.stop()
        self.listener.close()
        self.notify.close()


def account(soak: Soak) -> dict:
    from benchmarks import soak_account as A
    from benchmarks.soak_daemon import read_frame_log

    sent = list(soak.emulator.sent)
    handled = A.which_sent(sent, *read_frame_log(soak.frame_log))
    windows = A.fault_windows(soak.faults, sent, handled)
    t0, t_end = soak.t0, soak.t_end
    out: dict = {}
    out.update(A.frame_figures(sent, handled, windows, t0, t_end))
    out.update(A.event_figures(sent, handled, windows, soak.listener.events, soak.reference,
                               soak.recording.n_frames, t0, t_end, history=int(CLEAN_HISTORY_S * NOMINAL_RATE_HZ)))
    out.update(A.fault_figures(soak.faults, t0))
    out.update(A.watchdog_figures(soak.notify.pings, soak.faults, t0, t_end, WATCHDOG_S))
    out.update(A.rss_figures(soak.rss, soak.plan.seconds))
    swaps = soak.swaps
    log_rows = [{k: v for k, v in s.items() if k != "at"} for s in swaps]
    out["model_swaps"] = {"dropped": len(swaps), "right": sum(1 for s in swaps if s["ok"]),
                          "wrong": [s for s in log_rows if not s["ok"]], "log": log_rows}
    out["sighup_reloads"] = {"sent": len(soak.reloads), "acknowledged": soak.notify.counts["RELOADING=1"]}
    status = soak.final_status
    out["daemon_health"] = {k: status.get(k) for k in (
        "frames_received", "frames_dropped", "frames_stale", "crc_errors", "protocol_errors", "reconnects",
        "device_faults", "decisions", "events", "missed_deadlines", "models_loaded", "models_rejected",
        "latency_p50_us", "latency_p99_us", "latency_max_us", "last_error", "recent_errors")}
    out["emulator"] = soak.emulator.stats.as_dict()
    log = soak.stderr_path.read_text(errors="replace")
    out["daemon_log"] = {"lines": log.count("\n"), "tracebacks": log.count("Traceback"),
                         "tail": log.splitlines()[-5:]}
    return out


def run(args) -> dict:
    hours = float(args.hours if args.hours is not None else (0.01 if args.quick else 1.0))
    args.hours = hours
    say = args.say
    load_before = load_average()
    started = time.time()
    with tempfile.TemporaryDirectory(prefix="handover-soak-") as tmp:
        soak = Soak(args, Path(tmp))
        soak.prepare_models()
        soak.start()
        soak.reference = reference_events(soak.model_a, soak.recording, soak._config("warning"))
        say(f"soak: {hours * 60:.1f} min at 32 Hz against the emulator ({soak.server.url}); a fault every "
            f"{soak.plan.fault_every:.0f} s or once the last recovered and streamed clean, model drops every {soak.plan.swap_every:.0f} s, "
            f"SIGHUP every {soak.plan.hup_every:.0f} s")
        try:
            soak.run_schedule()
        finally:
            soak.finish()
        figures = account(soak)
    result = {"synthetic": True, "hours": hours, "seconds": round(soak.t_end - soak.t0, 1), **figures,
              "plan": soak.plan.__dict__, "watchdog_sec": WATCHDOG_S, "stall_timeout_s": STALL_TIMEOUT_S,
              "hostile_inputs": hostile_counts(args.out),
              "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(started)),
              "commit": _commit(), "machine": machine_info(), "load_before": load_before,
              "load_after": load_average(), "command": f"./dev bench soak --hours {hours:g} --seed {args.seed}"
              + ("" if args.out == "results" else f" --out {args.out}")}
    result["note"] = load_note(result["load_before"], result["load_after"], result["machine"]["cores"])
    write_results(args.out, NAME, result, markdown(result))
    return result


def hostile_counts(out: str | Path) -> dict:
    """The hostile-input benchmark's counts (``./dev bench hostile``, results/hostile.json) that a
    soak cites beside its own figures; None where that benchmark has not been run into ``out``."""
    path = Path(out) / "hostile.json"
    if not path.is_file():
        return {"source": None, "counts": None}
    from benchmarks.hostile import summary

    return {"source": str(path), "counts": summary(json.loads(path.read_text()))}


def _commit() -> str | None:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=harness.ROOT, capture_output=True,
                             text=True, timeout=5)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=harness.ROOT,
                               capture_output=True, text=True, timeout=5).stdout.strip()
        return out.stdout.strip() + ("-dirty" if dirty else "") if out.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        return None


def markdown(r: dict) -> list[str]:
    goal = lambda ok: "yes" if ok else "**no**"  # noqa: E731
    rows = [
        ("hours", r["hours"], ""),
        ("frames_expected", r["frames_expected"], ""),
        ("frames_lost_outside_injected_faults", r["frames_lost_outside_injected_faults"],
         goal(r["frames_lost_outside_injected_faults"] == 0)),
        ("frames_lost_inside_injected_faults", r["frames_lost_inside_injected_faults"], ""),
        ("faults_injected", r["faults_injected"], ""),
        ("faults_recovered", r["faults_recovered"], goal(r["faults_recovered"] == r["faults_injected"])),
        ("max_recovery_s", r["max_recovery_s"], ""),
        ("events_expected", r["events_expected"], ""),
        ("events_lost", r["events_lost"], goal(r["events_lost"] == 0)),
        ("rss_growth_mb", r["rss_growth_mb"], goal(r["rss_growth_mb"] is not None and r["rss_growth_mb"] < 5)),
        ("watchdog_would_fire_while_healthy", r["watchdog_would_fire_while_healthy"],
         goal(r["watchdog_would_fire_while_healthy"] == 0)),
        ("hangs caught / injected", f"{r['hangs_caught_by_watchdog']} / {r['hangs_injected']}",
         goal(r["hangs_caught_by_watchdog"] == r["hangs_injected"])),
        ("model drops right", f"{r['model_swaps']['right']} / {r['model_swaps']['dropped']}",
         goal(r["model_swaps"]["right"] == r["model_swaps"]["dropped"])),
        ("SIGHUP reloads acknowledged", f"{r['sighup_reloads']['acknowledged']} / {r['sighup_reloads']['sent']}",
         goal(r["sighup_reloads"]["acknowledged"] == r["sighup_reloads"]["sent"])),
    ]
    md = [f"# Soak: {r['hours']:g} h at 32 Hz against the emulator, faults injected on a schedule (synthetic)", "",
          "The daemon (`handover run`, its own process) against the emulated DSACON32m serving the simulated "
          "hand's session in a loop over TCP. Faults by kind (each recovered / injected, longest recovery):", ""]
    for kind, k in r["faults_by_kind"].items():
        md.append(f"- {kind}: {k['recovered']} / {k['injected']}, max {k['max_recovery_s']} s")
    md += ["", "| figure | value | goal met |", "|---|---|---|"]
    md += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    md += ["", f"Commit {r['commit']}, started {r['started_utc']}. {r['note']}",
           "Rules: see the docstring of benchmarks/soak.py (what counts as inside a fault, which events are "
           "expected)."]
    hostile = (r.get("hostile_inputs") or {}).get("counts")
    if hostile:
        md += ["", "Hostile inputs (`./dev bench hostile`, results/hostile.md): "
               + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in hostile.items()) + "."]
    return md
