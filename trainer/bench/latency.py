"""Latency per stage (decode, ring, trigger, inference) and end to end (emulator -> daemon -> UDP sink).

Stages are timed in this process on real-sized data: an RLE frame of the simulated hand in
contact (parser + CRC + decode), a ring push of all pads, a trigger update, one ONNX inference
of the default model (1 intra-op thread, spinning off). Each as fast as possible (back to back)
and paced at 32 Hz (the daemon's rhythm: caches and CPU clocks cool between frames).

End to end: ``handover run`` in its own process reads an emulated DSACON32m (another process)
over loopback TCP and sends each event to a UDP listener in this process. Latency = from the
emulator's socket write of the last byte of the frame that completes a window to the datagram's
arrival. The stream holds simulated trial windows back to back, each followed by just enough
untouched frames for the daemon's trigger to re-arm (``common.tap_gap``).
The deadline is one sample period (31.25 ms); every figure is also given as the ratio
deadline / figure (how many times it fits).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from trainer.bench import harness
from trainer.bench.common import (
    DEADLINE_US,
    command_line,
    deadline_ratio,
    fmt_us,
    load_average,
    load_note,
    machine_info,
    percentiles,
    tap_gap,
    tap_stream,
    time_calls,
    train_default_model,
    write_results,
)

NAME = "latency"
PERIOD_S = 1.0 / 32.0


def stage_fns(model, recording):
    """Zero-argument callables for each stage, on a frame of the stream in contact."""
    from firmware_io.parser import StreamParser
    from firmware_io.protocol import encode_frame
    from runtime.ring import RingBuffer
    from runtime.trigger import ThresholdTrigger

    layout = recording.layout
    n = layout.n_taxels
    sums = recording.frames.astype(np.int64).sum(axis=1)
    frame = recording.frames[int(np.argmax(sums))]  # the most taxels in contact: the longest RLE frame
    packet = encode_frame(frame, 123456, rle=True)
    parser = StreamParser(n)
    from firmware_io.protocol import decode_frame_payload

    def decode():
        (pkt,) = parser.feed(packet)
        decode_frame_payload(pkt.payload, n)

    T = model.meta.T
    cols = layout.columns(list(model.meta.pads))
    ring = RingBuffer(cols, 64)
    for row in recording.frames[: 2 * T]:
        ring.push(row)
    trigger = ThresholdTrigger(cols.size, model.meta.fullscale, window=T)
    counter = [0]

    def push():
        counter[0] += 1
        ring.push(frame, counter[0])

    def trig():
        counter[0] += 1
        trigger.update(ring.latest(), counter[0])

    window = ring.window(T)

    def infer():
        model.run(window)

    return {"decode": decode, "ring_push": push, "trigger": trig, "inference": infer}, len(packet)


def measure_stages(fns: dict, repeats: int, paced_s: float) -> dict:
    """Each stage back to back (``repeats`` calls) and paced at 32 Hz for ``paced_s`` seconds."""
    out = {}
    for name, fn in fns.items():
        n = repeats // 4 if name == "inference" else repeats
        out[name] = {"fast": percentiles(time_calls(fn, n, warmup=50))}
    n_paced = max(5, int(paced_s * 32))
    paced = {name: np.empty(n_paced) for name in fns}
    clock = time.perf_counter_ns
    next_t = time.perf_counter()
    for i in range(n_paced):
        next_t += PERIOD_S
        pause = next_t - time.perf_counter()
        if pause > 0:
            time.sleep(pause)
        for name, fn in fns.items():
            t0 = clock()
            fn()
            paced[name][i] = (clock() - t0) / 1000.0
    for name in fns:
        out[name]["32hz"] = percentiles(paced[name])
    return out


def end_to_end(model_path: Path, recording, speed: float | None, work: Path, timeout: float) -> dict:
    """One run of the rig; latencies in us and counts."""
    listener = harness.UdpListener()
    emulator = harness.EmulatorProcess(recording, speed)
    models = work / f"models-{speed}"
    harness.install_model(model_path, models)
    config = harness.write_config(work, emulator.url, models, listener.port)
    daemon = harness.spawn_daemon(config)
    try:
        stamps = emulator.wait_stamps(timeout)
        time.sleep(0.5)  # the last datagram
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
            "missed_deadline": int(sum(v > DEADLINE_US for v in lat))}


def run(args) -> dict:
    from runtime.model import load_model

    say = args.say
    load_before = load_average()
    t_start = time.perf_counter()
    duration = args.duration if args.duration is not None else (3.0 if args.quick else 300.0)
    n_windows = max(4, int(duration * 32 / (15 + tap_gap())))
    result: dict = {"synthetic": True, "deadline_us": DEADLINE_US}
    with tempfile.TemporaryDirectory(prefix="handover-latency-") as tmp:
        work = Path(tmp)
        say("latency: training the default model on the simulated protocol (synthetic) ...")
        model_path = train_default_model(work, seed=args.seed, quick=args.quick)
        model = load_model(model_path, intra_op_threads=1, allow_spinning=False)
        stream = tap_stream(args.seed, args.quick, n_windows=n_windows, gap=tap_gap())
        fns, packet_bytes = stage_fns(model, stream)
        repeats = 400 if args.quick else 20000
        paced_s = 1.0 if args.quick else 60.0
        say(f"latency: stages back to back and paced at 32 Hz ({paced_s:.0f} s) ...")
        result["stages"] = measure_stages(fns, repeats, paced_s)
        result["frame_packet_bytes"] = packet_bytes
        say(f"latency: end to end at 32 Hz for {stream.n_frames / 32:.0f} s ({n_windows} windows) ...")
        result["e2e_32hz"] = end_to_end(model_path, stream, 1.0, work, timeout=stream.n_frames / 32 + 60)
        fast_stream = tap_stream(args.seed, args.quick, n_windows=max(4, n_windows // 2), gap=tap_gap())
        say("latency: end to end as fast as possible ...")
        result["e2e_max"] = end_to_end(model_path, fast_stream, None, work, timeout=120)
        if args.load:
            load_s = max(2.0, duration / 5)
            load_stream = tap_stream(args.seed, args.quick, n_windows=max(4, int(load_s * 32 / (15 + tap_gap()))), gap=tap_gap())
            say(f"latency: under load (two busy-loop processes) for {load_s:.0f} s ...")
            with harness.CpuLoad(2):
                result["stages_load"] = measure_stages(fns, repeats // 4, paced_s / 4)
                result["e2e_32hz_load"] = end_to_end(model_path, load_stream, 1.0, work,
                                                     timeout=load_stream.n_frames / 32 + 60)
    e2e = result["e2e_32hz"]["e2e_us"]
    result.update(
        model={"K": model.meta.K, "W": model.meta.W, "T": model.meta.T, "n_channels": model.meta.n_channels,
               "n_nodes": model.n_nodes, "pads": list(model.meta.pads)},
        onnx_p50_us=result["stages"]["inference"]["fast"]["p50"],
        onnx_p99_us=result["stages"]["inference"]["fast"]["p99"],
        e2e_p50_us=e2e["p50"], e2e_p99_us=e2e["p99"], e2e_p999_us=e2e["p999"], e2e_max_us=e2e["max"],
        duration_s=duration,
        window_period_frames=15 + tap_gap(),
        seconds=round(time.perf_counter() - t_start, 1),
        machine=machine_info(),
        load_before=load_before,
        load_after=load_average(),
        command=command_line(NAME, args),
    )
    if "e2e_32hz_load" in result:
        result["e2e_load_p99_us"] = result["e2e_32hz_load"]["e2e_us"]["p99"]
    result["note"] = load_note(result["load_before"], result["load_after"], result["machine"]["cores"])
    plot(result, Path(args.out) / f"{NAME}.png")
    write_results(args.out, NAME, result, markdown(result))
    return result


def _row(name: str, s: dict) -> str:
    r = deadline_ratio(s)
    ratio = " / ".join("-" if r[k] is None else f"{r[k]:,.0f}x" for k in ("p50", "p99", "p999", "max"))
    return (f"| {name} | {fmt_us(s['p50'])} | {fmt_us(s['p99'])} | {fmt_us(s['p999'])} | {fmt_us(s['max'])} | "
            f"{s['n']} | {ratio} |")


def markdown(res: dict) -> list[str]:
    head = ["| what | median (us) | p99 (us) | p99.9 (us) | max (us) | n | deadline / figure (p50 / p99 / p99.9 / max) |",
            "|---|---|---|---|---|---|---|"]
    m = res["model"]
    lines = ["# Latency by stage and end to end (synthetic data)", "",
             f"Deadline: one sample period, {DEADLINE_US:.0f} us at 32 Hz. Model: the default (K={m['K']}, "
             f"W={m['W']}, T={m['T']}, {m['n_channels']} taxels of pads {m['pads']}, {m['n_nodes']} nodes) trained "
             "on the simulated protocol (synthetic). The last column says how many times each figure fits into "
             "the deadline.", "", "![latency](latency.png)", "", "## Stages (this process)", "", *head]
    for key, title in (("stages", ""), ("stages_load", " under load")):
        if key not in res:
            continue
        for name, s in res[key].items():
            lines.append(_row(f"{name}, back to back{title}", s["fast"]))
            lines.append(_row(f"{name}, paced at 32 Hz{title}", s["32hz"]))
    lines += ["", f"Decode = StreamParser.feed + CRC + decode_frame_payload of one RLE frame of {res['frame_packet_bytes']} "
              "bytes (the frame of the stream with the most contact); ring = RingBuffer.push of all pads; "
              "inference = LoadedModel.run on one window (input check included).", "",
              "## End to end (emulator process -> loopback TCP -> `handover run` -> UDP -> listener)", "", *head]
    for key, title in (("e2e_32hz", "end to end at 32 Hz"), ("e2e_32hz_load", "end to end at 32 Hz, under load"),
                       ("e2e_max", "end to end, frames as fast as possible (includes queueing)")):
        if key in res:
            e = res[key]
            lines.append(_row(title, e["e2e_us"]))
            lines.append(_row(f"({title}: inside the daemon, frame parsed -> decision)", e["daemon_internal_us"]))
    lines += [""]
    for key in ("e2e_32hz", "e2e_32hz_load", "e2e_max"):
        if key in res:
            e = res[key]
            lines.append(f"- {key}: {e['windows_sent']} windows sent (one every {res['window_period_frames']} frames), {e['events']} events received "
                         f"({e['unmatched']} not matched to a frame), {e['missed_deadline']} over the deadline.")
    lines += ["", "Under load = two busy-loop processes, one per core, during the run." if "e2e_32hz_load" in res
              else "No run under load (add --load).", "", res["note"]]
    return lines


def plot(res: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    names, p50, p99, mx = [], [], [], []
    for name, s in res["stages"].items():
        names.append(f"{name} (32 Hz)")
        p50.append(s["32hz"]["p50"])
        p99.append(s["32hz"]["p99"])
        mx.append(s["32hz"]["max"])
    for key, title in (("e2e_32hz", "end to end"), ("e2e_32hz_load", "end to end, load")):
        if key in res:
            s = res[key]["e2e_us"]
            names.append(title)
            p50.append(s["p50"])
            p99.append(s["p99"])
            mx.append(s["max"])
    fig, ax = plt.subplots(figsize=(8, 4.5))
    y = np.arange(len(names))
    ax.barh(y - 0.25, p50, 0.25, label="median")
    ax.barh(y, p99, 0.25, label="p99")
    ax.barh(y + 0.25, mx, 0.25, label="max")
    ax.axvline(DEADLINE_US, color="red", ls="--", label="deadline 31.25 ms")
    ax.set_xscale("log")
    ax.set_yticks(y, names)
    ax.invert_yaxis()
    ax.set_xlabel("microseconds (log scale)")
    ax.set_title("Latency by stage and end to end (synthetic stream)")
    ax.legend(fontsize=8)
    ax.grid(True, axis="x", which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
