"""Latency by stage (frame bytes to the sink's send) and end to end (emulator -> daemon -> UDP sink).

Stages: ``latency_stages`` drives the real client (parser, decoder, plausibility check) and
``Daemon.handle_frame`` in this process, back to back and paced at 32 Hz, quiet and (``--load``)
with two busy-loop processes; the daemon's own stamps (``runtime.listeners``) split each
decision. The graph alone is timed one window at a time, for the default model on all pads and
on the distal pads (the graph against scikit-learn is ``handover bench inference``'s question).

End to end: ``handover run`` in its own process reads an emulated DSACON32m (another process)
over loopback TCP and sends each event to a UDP listener in this process. Latency = from the
emulator's socket write of the last byte of the frame that completes a window to the datagram's
arrival. The stream holds simulated trial windows back to back, each followed by just enough
untouched frames for the daemon's trigger to re-arm (``trainer.measure.tap_gap``). The daemon's resident
memory is read from /proc at the end of that run.
The deadline is one sample period (``trainer.measure.DEADLINE_US``); every figure is also given as the ratio
deadline / figure (how many times it fits).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from firmware_io.frame_timing import NOMINAL_PERIOD_S
from runtime import realtime
from runtime.realtime import DEFAULT_PRIORITY
from trainer.bench import harness
from trainer.bench import latency_stages as stages
from trainer.bench.latency_early import early_frames, early_model
from trainer.bench.latency_floor import interference, per_frame_split
from trainer.bench.latency_report import headline, job_lengths, markdown, plot
from trainer.bench.latency_shadow import shadow_cases
from trainer.measure import (
    DEADLINE_US,
    deadline_ratio,
    load_average,
    percentiles,
    run_facts,
    tap_gap,
    tap_stream,
    train_default_model,
    write_results,
)

NAME = "latency"


def end_to_end(model_path: Path, recording, speed: float | None, work: Path, timeout: float,
               priority: int = DEFAULT_PRIORITY) -> dict:
    """One run of the rig; latencies in us, counts, and the daemon's resident memory at the end.
    The daemon's ``realtime_priority``, the emulator's and the listener's are ``priority`` (the
    daemon's default: as the shipped config runs it; 0: normal scheduling throughout)."""
    from trainer.bench.throughput import proc_mem_mb

    listener = harness.UdpListener(priority)
    emulator = harness.EmulatorProcess(recording, speed, priority)
    models = work / f"models-{speed}"
    harness.install_model(model_path, models)
    config = harness.write_config(work, emulator.url, models, listener.port, realtime_priority=priority)
    daemon = harness.spawn_daemon(config)
    mem: dict = {}
    try:
        stamps = emulator.wait_stamps(timeout)
        time.sleep(0.5)  # the last datagram
        if daemon.poll() is None:
            mem = proc_mem_mb(daemon.pid)
    finally:
        harness.stop_daemon(daemon)
        emulator.close()
        listener.close()
    stderr = (daemon.stderr.read() if daemon.stderr else "")[-2000:]
    lat, internal, unmatched = [], [], 0
    for t, ev in listener.events:
        sent = stamps.get(int(ev.get("device_time_ms", -1)))
        if sent is None:
            unmatched += 1
            continue
        lat.append((t - sent) * 1e6)
        internal.append(float(ev.get("latency_us", 0.0)))
    if not lat:
        raise RuntimeError(f"no event reached the UDP sink (daemon log: {stderr.strip()[-300:] or 'empty'})")
    stats = percentiles(lat)
    return {"speed": "max" if speed is None else speed, "e2e_us": stats, "deadline_ratio": deadline_ratio(stats),
            "daemon_internal_us": percentiles(internal), "events": len(listener.events), "unmatched": unmatched,
            "windows_sent": len(recording.trials), "frames_sent": len(stamps),
            "missed_deadline": int(sum(v > DEADLINE_US for v in lat)), "realtime_priority": priority, "rss_mb": mem.get("VmRSS"),
            "rss_peak_mb": mem.get("VmHWM")}


def case_windows(model, recording) -> np.ndarray:
    """float32 ``[n, T, C]``: the window of each trial of the stream, the model's columns."""
    T = model.meta.T
    cols = recording.layout.columns(list(model.meta.pads))
    return np.stack([recording.frames[t.first : t.first + T][:, cols] for t in recording.trials]).astype(np.float32)


def implementations(model_path: Path, stream, rounds: int, load: bool) -> dict:
    """The graph on the stream's windows: alone (``solo``), back to back and paced, quiet (and loaded)."""
    from runtime.model import load_model

    model = load_model(model_path, intra_op_threads=1, allow_spinning=False)
    fns = stages.comparators(model)
    windows = case_windows(model, stream)
    out = {"solo": stages.solo(fns, windows, rounds),
           "back_to_back": stages.compare(fns, windows, rounds, paced=False),
           "paced_32hz": stages.compare(fns, windows, max(20, rounds // 10), paced=True),
           "paced_asleep": {"onnxruntime": stages.paced_alone(fns["onnxruntime"], windows, max(20, rounds // 10), False)},
           "paced_rehearsed": {"onnxruntime": stages.paced_alone(fns["onnxruntime"], windows, max(20, rounds // 10), True)},
           "binding": stages.solo(binding_comparators(model), windows, rounds)}
    if load:
        with harness.CpuLoad(2):
            out["back_to_back_load"] = stages.compare(fns, windows, max(20, rounds // 4), paced=False)
    out["per_frame_split"] = per_frame_split(model_path, windows, rounds)
    return out


def binding_comparators(model) -> dict:
    """One window through ``run_trusted`` (as the daemon runs it: copied to one aligned array, then
    ``session.run``) and through a plain ``session.run`` on the ring's view."""
    from runtime.model import INPUT_NAME, OUTPUT_NAMES

    session = model._session
    return {"staged": lambda w: model.run_trusted(w[None]),
            "session_run": lambda w: session.run(OUTPUT_NAMES, {INPUT_NAME: w[None]})}


def heap_figures(rounds: int = 7) -> dict:
    """Microseconds (median of ``rounds``) of a full collection in this process (models, numpy, onnxruntime
    and scikit-learn loaded) with every object visible to the collector and after ``gc.freeze``
    (``runtime.heap.settle_heap``, what the daemon does once started); and of a young collection of 700
    fresh objects (the collector's default threshold), what automatic collection costs when it runs."""
    import gc

    def timed(generation: int, fresh: int = 0) -> float:
        times = []
        for _ in range(rounds):
            junk = [[] for _ in range(fresh)]
            t0 = time.perf_counter_ns()
            gc.collect(generation)
            times.append((time.perf_counter_ns() - t0) / 1000.0)
            del junk
        return float(np.median(times))

    gc.unfreeze()
    out = {"full_us": timed(2)}
    gc.freeze()
    try:
        out.update(full_frozen_us=timed(2), young_us=timed(0, fresh=700), frozen_objects=gc.get_freeze_count())
    finally:
        gc.unfreeze()
    return out


def run(args) -> dict:
    from runtime.model import load_model
    from runtime.onnx_wire import summarize

    say = args.say
    load_before = load_average()
    t_start = time.perf_counter()
    duration = args.duration if args.duration is not None else (3.0 if args.quick else 120.0)
    n_windows = max(4, int(duration * 32 / (15 + tap_gap())))
    paced_decisions = 16 if args.quick else 1000  # quick: every stage and block seen, not a distribution
    rounds = 200 if args.quick else 3000
    result: dict = {"synthetic": True, "deadline_us": DEADLINE_US}
    with tempfile.TemporaryDirectory(prefix="handover-latency-") as tmp:
        work = Path(tmp)
        say("latency: training the default model on all pads and on the distal pads (synthetic) ...")
        model_path = train_default_model(work, seed=args.seed, quick=args.quick)
        distal_path = train_default_model(work, seed=args.seed, quick=args.quick, name="distal.onnx", pads="distal")
        model = load_model(model_path, intra_op_threads=1, allow_spinning=False)
        dormant = model.meta.classes[-1]  # declared dormant for the continuous-mode table (timing only)
        distal_nodes = summarize(distal_path.read_bytes()).n_nodes  # as load_model counts them, without a session
        dense = tap_stream(args.seed, args.quick, n_windows=paced_decisions + 10, gap=tap_gap())
        say(f"latency: stage table, back to back, paced at 32 Hz and in continuous mode ({paced_decisions} "
            "decisions) ...")
        say("latency: the default model with and without early heads (synthetic) ...")
        early_paths = early_model(work, args.seed, args.quick)  # trained at normal priority
        before, result["scheduling"] = realtime.enter_realtime(DEFAULT_PRIORITY)  # as the daemon's hot thread
        try:
            continuous = load_model(stages.declared_dormant(model_path, work / "continuous.onnx", dormant),
                                    intra_op_threads=1, allow_spinning=False)
            result["stages"] = stages.stage_tables(model, dense, paced_decisions, continuous)
            say("latency: serving with a candidate in shadow, against serving alone (alternating blocks) ...")
            result["shadow"] = shadow_cases(model, dense, paced_decisions, work)
            result["early_frames"] = early_frames(early_paths, args.seed, args.quick, say)  # at the hot thread's priority
            say("latency: the machine's interference (a spinning thread) ...")
            gaps = interference(0.5 if args.quick else 10.0)
            if args.load:
                say("latency: stage table under load (two busy-loop processes) ...")
                with harness.CpuLoad(2):
                    result["stages_load"] = stages.stage_tables(model, dense, max(30, paced_decisions // 4))
        finally:
            realtime.restore(before)
        say("latency: the graph alone, all pads and distal pads ...")
        result["implementations"] = implementations(model_path, dense, rounds, args.load)
        result["implementations_distal"] = implementations(distal_path, dense, rounds, False)
        result["heap"] = heap_figures()
        stream = tap_stream(args.seed, args.quick, n_windows=n_windows, gap=tap_gap())
        say(f"latency: end to end at 32 Hz for {stream.n_frames * NOMINAL_PERIOD_S:.0f} s ({n_windows} windows) ...")
        result["e2e_32hz"] = end_to_end(model_path, stream, 1.0, work, timeout=stream.n_frames * NOMINAL_PERIOD_S + 60)
        if args.load:
            load_s = max(2.0, duration / 4)
            load_stream = tap_stream(args.seed, args.quick, n_windows=max(4, int(load_s * 32 / (15 + tap_gap()))),
                                     gap=tap_gap())
            say(f"latency: end to end under load (two busy-loop processes) for {load_s:.0f} s ...")
            with harness.CpuLoad(2):
                result["e2e_32hz_load"] = end_to_end(model_path, load_stream, 1.0, work,
                                                     timeout=load_stream.n_frames * NOMINAL_PERIOD_S + 60)
            say(f"latency: the same under load at normal scheduling (realtime_priority = 0) for {load_s:.0f} s ...")
            with harness.CpuLoad(2):
                result["e2e_32hz_load_normal"] = end_to_end(model_path, load_stream, 1.0, work,
                                                            timeout=load_stream.n_frames * NOMINAL_PERIOD_S + 60, priority=0)
    result["interference"] = {**gaps.summary(), "steady_job_us": {
        name: {"job_us": round(job), **gaps.steady_job(round(job), seed=args.seed)}
        for name, job in job_lengths(result).items() if job}}
    result.update(headline(result))
    result.update(
        model={"kind": model.meta.extra.get("model_kind"), "K": model.meta.K, "W": model.meta.W, "T": model.meta.T,
               "n_channels": model.meta.n_channels, "n_nodes": model.n_nodes, "pads": list(model.meta.pads),
               "n_nodes_distal": distal_nodes, "continuous_dormant": dormant},
        duration_s=duration, window_period_frames=15 + tap_gap(), **run_facts(NAME, args, load_before, t_start),
    )
    plot(result, Path(args.out) / f"{NAME}.png")
    write_results(args.out, NAME, result, markdown(result))
    return result
