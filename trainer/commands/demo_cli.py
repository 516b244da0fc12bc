"""``handover demo``: the whole product end to end on the simulated hand (synthetic data).

Simulates the paper's protocol, trains, evaluates and exports the default model, serves an emulated
controller playing a session of unseen simulated subjects, runs the real daemon against it and
compares its events with the script (``trainer.streams_eval.session_outcomes``). The model is trained
with the daemon's default stream setting (``--trigger``), which it records and the daemon then uses.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from firmware_io.commands.options import add_json, add_lab, add_out, add_quiet, add_seed
from firmware_io.errors import HandoverError
from firmware_io.sim.session import DEMO_TRAIN_SEED, HELD_OUT_SEED_OFFSET

if TYPE_CHECKING:
    from firmware_io.recordings.recording import Recording
    from firmware_io.sim.session import ScriptedEvent

__all__ = ["add_arguments", "main"]

SETTINGS = ("onset", "onset_dormant", "continuous", "threshold")
STREAM_MODEL_IDLE_MIN, STREAM_MODEL_SESSIONS = 10.0, 60
"""Training data of the 5-class stream model (as ``./dev bench streams`` trains it)."""
DEMO_EVENTS = 40
"""Scripted events in the demo's session (``--events``); the streams benches replay the same session."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_out(parser, "working folder (data, report, models; default out/demo)", default="out/demo")
    parser.add_argument("--events", type=int, default=DEMO_EVENTS,
                        help=f"scripted events in the session (default {DEMO_EVENTS})")
    add_seed(parser, DEMO_TRAIN_SEED, f"seed of the training data (default {DEMO_TRAIN_SEED}); the session plays "
             f"seed + {HELD_OUT_SEED_OFFSET}")
    add_lab(parser, "the session's hand and people (the demo's model trains on lab A's either way; B's with --model "
            "trained on B's recordings)")
    parser.add_argument("--pads", default="all", help="pads the model and the scene use (default all)")
    parser.add_argument("--speed", default="1.0", help="session playback: 1.0 = real time at 32 Hz, 'max' = as fast "
                        "as possible (latency figures then include queueing)")
    parser.add_argument("--fault", default="", help="faults the emulator injects, e.g. crc=0.01,garbage=0.01")
    parser.add_argument("--setting", choices=SETTINGS, default=None,
                        help="stream setting (default: the one results/streams.md chose by its rule, "
                        "trainer.streams_eval.DEFAULT_SETTING): onset = onset trigger + 4-class model, onset_dormant "
                        "= onset trigger + 5-class model with a dormant class, continuous = every frame classified, "
                        "threshold = the paper's 15 %% level")
    parser.add_argument("--retrain", action="store_true", help="train again even if OUT/report/stream-model.onnx exists (OUT/report/model.onnx "
                        "for --setting threshold)")
    parser.add_argument("--model", help="score this model file (e.g. report/model.onnx from handover train) on the "
                        "same scripted session instead of training one: compare your model with the demo's on the "
                        "same events (the stream setting follows the model: onset_dormant with a dormant class, "
                        "else its recorded trigger; --setting continuous classifies every frame)")
    add_json(parser, "the summary (stdout holds it alone; the events and steps go to stderr)")
    add_quiet(parser, "only the summary")


def _say(args: argparse.Namespace, text: str) -> None:
    if not args.quiet:
        print(text, file=sys.stderr if args.json else sys.stdout, flush=True)


def setting_of(args: argparse.Namespace) -> str:
    from trainer.streams_eval import DEFAULT_SETTING

    return args.setting or getattr(args, "model_setting", None) or DEFAULT_SETTING


def given_model(args: argparse.Namespace) -> Path:
    """``--model``, checked as the daemon would load it; sets the stream setting it serves (ValueError: one line)."""
    from runtime.model import ModelContractError, load_model
    from runtime.stream_settings import served_settings

    path = Path(args.model)
    try:
        model = load_model(path, warm_up=False)
    except ModelContractError as exc:
        raise ValueError(f"--model: {exc}") from None
    meta = model.meta
    served = served_settings(meta.dormant_class, meta.trigger)
    served = [n.replace("threshold_dormant", "threshold") for n in served]  # the demo's names
    if args.setting and args.setting not in served:
        raise ValueError(f"--model {path} serves the stream settings {', '.join(served)}, not --setting "
                         f"{args.setting}" + ("; continuous mode needs a dormant class" if args.setting == "continuous"
                                              else ""))
    args.model_setting = served[0]
    if args.pads == "all":
        args.pads = ",".join(str(p) for p in meta.pads)
    _say(args, f"[1-2/4] your model {path} (id {model.model_id}; no simulation, no training), served in setting "
               f"{setting_of(args)}")
    return path


def train_model(args: argparse.Namespace, out: Path) -> Path:
    """Simulate, train, evaluate and export (``handover train``, or the 5-class stream model for the
    settings that need one); reuse an earlier model unless --retrain."""
    setting = setting_of(args)
    report = out / "report"
    model = report / ("stream-model.onnx" if setting in ("onset_dormant", "continuous") else "model.onnx")
    stamp = report / "demo-args.json"
    wanted = {"seed": args.seed, "pads": args.pads, "model": model.name, "early": True,
              "trigger": "threshold" if setting == "threshold" else "onset"}
    if model.is_file() and not args.retrain and stamp.is_file() and json.loads(stamp.read_text()) == wanted:
        _say(args, f"[1-2/4] reusing the trained model {model} (--retrain to train again)")
        return model
    if model.name == "stream-model.onnx":
        return _train_stream_model(args, model, stamp, wanted)
    from trainer.pipeline import train
    from trainer.report import pooled_text
    from trainer.train_options import TrainOptions

    _say(args, f"[1/4] simulating the paper's protocol (synthetic, seed {args.seed}) and [2/4] training ...")
    result = train(TrainOptions(out=str(report), pads=args.pads, seed=args.seed, trigger=wanted["trigger"], repeats=3,
                                no_sweep=True, replay=False, quiet=args.quiet or args.json))
    if result.exit_code != 0 or not model.is_file():
        raise RuntimeError("training did not produce model.onnx (see the messages above)")
    stamp.write_text(json.dumps(wanted))
    metrics = result.metrics
    _say(args, result.headline)
    _say(args, f"      synthetic data: {metrics['n_cases']} cases ({metrics['n_untriggered']} trials never "
               f"triggered); leave-one-subject-out accuracy {metrics['loso_accuracy']:.1%}, pooled 80/20 "
               f"{pooled_text(metrics['config1'])}; report {report / 'report.md'}")
    return model


def _train_stream_model(args: argparse.Namespace, model: Path, stamp: Path, wanted: dict) -> Path:
    """The 5-class model with a dormant class and level features (trainer.dormant.fit_stream_model)."""
    from firmware_io.sim import simulate_protocol
    from trainer.dormant import fit_stream_model

    _say(args, f"[1/4] simulating the paper's protocol, {STREAM_MODEL_IDLE_MIN:g} min of idle stream and "
               f"{STREAM_MODEL_SESSIONS} handovers (synthetic, seed {args.seed}) and [2/4] training the 5-class "
               "stream model (actions + dormant, level features) ...")
    model.parent.mkdir(parents=True, exist_ok=True)
    fit_stream_model(simulate_protocol(seed=args.seed), args.seed, STREAM_MODEL_IDLE_MIN, STREAM_MODEL_SESSIONS,
                     model, pads=args.pads)
    stamp.write_text(json.dumps(wanted))
    return model


def playback_text(duration_s: float, speed: float | None) -> str:
    """What the session will take on the wall clock, not its length in device time."""
    if speed is None:
        return f"{duration_s:.0f} s of device time replayed as fast as possible (a few seconds)"
    if speed == 1.0:
        return f"{duration_s:.0f} s in real time"
    return f"{duration_s:.0f} s of device time at speed {speed:g}: about {duration_s / speed:.0f} s"


def drop_model(model: Path, folder: Path) -> Path:
    """Install a model the safe way the daemon expects: temp name in the folder, then rename."""
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("*.onnx"):
        old.unlink()
    tmp = folder / f".{model.name}.tmp"
    shutil.copyfile(model, tmp)
    os.chmod(tmp, 0o644)
    final = folder / "demo.onnx"
    os.replace(tmp, final)
    return final


def main(args: argparse.Namespace) -> int:
    from firmware_io.commands.playback import playback_options

    if args.events < 4:
        raise HandoverError("--events must be at least 4 (one of each class)")
    try:
        speed, faults = playback_options(args.speed, args.fault)
    except ValueError as exc:
        raise HandoverError(str(exc)) from None
    out = Path(args.out)
    t_start = time.perf_counter()
    try:
        model_path = given_model(args) if args.model else train_model(args, out)
    except (OSError, ValueError, RuntimeError) as exc:
        raise HandoverError(str(exc)) from exc
    model_dir = drop_model(model_path, out / "models").parent
    summary = run_session(args, model_dir, speed, faults)
    summary.update(model=str(model_path), seconds=round(time.perf_counter() - t_start, 1))
    if args.json:
        print(json.dumps(summary))
    else:
        _print_summary(summary)
    return 0


def scripted_session(seed: int, events: int = DEMO_EVENTS, lab: str | None = None
                     ) -> tuple[int, list[ScriptedEvent], Recording]:
    """The demo's scripted session for training seed ``seed`` played by ``lab``'s hand and people (default
    A): (its own seed, the script, the simulated session); ``./dev bench streams`` and ``streams_own``
    replay the same one in process."""
    from firmware_io.sim import demo_script, simulate_session
    from firmware_io.sim.lab import get_lab

    session_seed, lab_ = seed + HELD_OUT_SEED_OFFSET, get_lab(lab)
    script = demo_script(events, seed=session_seed, objects=lab_.objects)
    return session_seed, script, simulate_session(script, seed=session_seed, lab=lab_)


def run_session(args: argparse.Namespace, model_dir: Path, speed: float | None, faults) -> dict:
    """Steps 3 and 4: an emulated DSACON32m plays a scripted session of unseen simulated subjects to
    the real daemon serving ``model_dir``; every event is printed as it happens. The summary."""
    from firmware_io.emulator.device import DeviceEmulator
    from firmware_io.emulator.server import TcpEmulatorServer
    from runtime.daemon import Daemon
    from runtime.sdnotify import Notifier

    session_seed, script, session = scripted_session(args.seed, args.events, args.lab)
    emulator = DeviceEmulator(session, speed=speed, loop=False, faults=faults, seed=session_seed,
                              session_starts="first_acquisition")  # the whole session, however long the daemon takes to start
    server = TcpEmulatorServer(emulator, host="127.0.0.1", port=0).start()
    duration = session.timestamps[-1] - session.timestamps[0]
    _say(args, f"[3/4] emulated DSACON32m on {server.url}: scripted session of {len(script)} events by unseen "
               f"simulated subjects (synthetic, seed {session_seed}, lab {args.lab}), {playback_text(duration, speed)}")
    events = EventLog(args, session, script, emulator)
    daemon = Daemon(_daemon_config(args, server.url, model_dir), notifier=Notifier({}), on_event=events.on_event)
    _say(args, "[4/4] daemon running with the exported model; events as they happen:")

    def stop_when_done() -> None:
        while not emulator.finished:
            time.sleep(0.2)
        time.sleep(1.5)  # let the last window complete
        daemon.request_stop()

    threading.Thread(target=stop_when_done, name="demo-stop", daemon=True).start()
    try:
        daemon.run()
    finally:
        server.stop()
    summary = {**_summary(args, daemon, events.decisions, session.trials), "real_time": speed == 1.0}
    if speed != 1.0:  # in the JSON too: missed deadlines there are the replay's bursts, not the daemon's time
        summary["latency_note"] = (f"replayed at speed {summary['replayed_at']}: frames arrive in bursts and a "
                                   "frame's arrival -> decision includes the frames queued before it; at speed 1.0 "
                                   "it is the daemon's own time")
    return summary


def _daemon_config(args: argparse.Namespace, url: str, model_dir: Path):
    from runtime.config import Config, DeviceConfig, ModelConfig, SceneConfig, SinksConfig

    return Config(
        device=DeviceConfig(url=url, stall_timeout_s=2.0, reconnect_min_s=0.2, reconnect_max_s=1.0),
        scene=SceneConfig(pads=args.pads, mode="continuous" if setting_of(args) == "continuous" else "trigger"),
        model=ModelConfig(folder=str(model_dir), poll_interval_s=0.5),
        sinks=SinksConfig(stdout=False),
        log_level="warning",
    )


class EventLog:
    """The daemon's events as they happen: each matched to the scripted event it answers, printed."""

    def __init__(self, args: argparse.Namespace, session, script, emulator) -> None:
        from trainer.streams_eval import Decision

        self.decision_of = Decision
        self.session, self.clock = session, None  # device time -> frame, as handover score maps it
        self.args, self.script, self.emulator = args, script, emulator
        self.trials = session.trials
        self.firsts = np.array([t.first for t in self.trials])
        self.decisions: list = []
        self.answered: set[int] = set()

    def on_event(self, event) -> None:
        args, trials = self.args, self.trials
        if self.clock is None:  # the session started when the daemon first asked for frames
            from firmware_io.emulator.script_file import session_script

            self.clock = session_script(self.session, self.emulator.session_clock_ms or 0)
        _, idx = self.clock.frame_of(event.device_time_ms)
        self.decisions.append(self.decision_of(idx, event.cls, event.latency_us))
        k = int(np.searchsorted(self.firsts, idx, side="right")) - 1
        if k < 0 or idx > trials[k].last:
            _say(args, f"  event {event.cls:<5} at frame {idx:5d}  {event.latency_us:7.0f} us  (no scripted event here)")
        elif k not in self.answered:
            self.answered.add(k)
            mark = "ok " if event.cls == trials[k].action else "WRONG"
            ev = self.script[k]
            _say(args, f"  event {event.cls:<5} at frame {idx:5d}  {event.latency_us:7.0f} us  {mark} scripted "
                       f"{ev.action} ({ev.subject}, {ev.object}, pose {ev.pose}; onset frame {trials[k].extra['onset']})")


def _summary(args: argparse.Namespace, daemon, decisions: list, trials) -> dict:
    from trainer.measure import DEADLINE_US
    from trainer.session_score import outcome_summary
    from trainer.streams_eval import session_outcomes

    h = daemon.health
    latency = daemon.reporter.latency.counters()  # the reporter owns the latencies (p50, p99, max)
    o = session_outcomes(decisions, trials)
    return {
        "synthetic": True,
        "lab": args.lab,
        "setting": setting_of(args),
        "trigger": daemon.detector.trigger_settings.name if daemon.detector.trigger_settings else None,
        **outcome_summary(o),
        "decisions": int(h.decisions),
        **latency, "latency_max_us": latency["latency_max_us"] if h.decisions else None,
        "deadline_us": DEADLINE_US,
        "replayed_at": args.speed,
        "missed_deadlines": int(h.missed_deadlines),
        "frames_received": int(h.frames_received),
        "frames_dropped": int(h.frames_dropped),
        "crc_errors": int(h.crc_errors),
        "models_taken_out": int(h.models_quarantined),
        "last_error": h.last_error,
    }


def _print_summary(s: dict) -> None:
    from trainer.session_score import summary_lines

    def us(v: float | None) -> str:
        return "-" if v is None else f"{v:.0f} us"

    print()
    print(f"summary (synthetic session, unseen simulated subjects of lab {s.get('lab', 'A')})")
    for line in summary_lines(s, s["setting"]):
        print(line)
    print(f"  latency frame arrival -> decision over {s['decisions']} decisions: median {us(s['latency_p50_us'])}, "
          f"p99 {us(s['latency_p99_us'])}, max {us(s['latency_max_us'])}; deadline {s['deadline_us']:.0f} us; "
          f"missed deadlines {s['missed_deadlines']}")
    if s.get("latency_note"):
        print(f"  ({s['latency_note']})")
    print(f"  frames: {s['frames_received']} received, {s['frames_dropped']} dropped, {s['crc_errors']} CRC errors")
    if s.get("models_taken_out"):  # else a session that lost its model reads as a model that misses events
        print(f"  the model was taken out of service during the session ({s['last_error']}): the events after it "
              "were not decided; on a busy machine run the demo again when it is quieter")
    print(f"  total {s['seconds']:.0f} s")
    print(f"  model: {s['model']} (the README's \"daemon without a hand\" serves it; handover inspect {s['model']})")

