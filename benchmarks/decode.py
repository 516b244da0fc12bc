"""``./dev bench decode``: DSACON32m full-frame decoding, RLE and raw, in frames per second on one core.

Frames come from the real SDH-2 recordings in ../shared/data (via the .dsa importer) when
present, else from simulated frames (then labelled synthetic). Each frame is encoded as the
controller would send it, then timed two ways:

- ``payload``: ``decode_frame_payload`` alone (what the issue's 20,000 frames/s aim is about);
- ``stream``: ``StreamParser.feed`` on the byte stream (preamble search, CRC) plus decoding.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import numpy as np

from trainer.measure import command_line, load_average, machine_info, write_results
from trainer.shared_data import default_data_dir

DATA = default_data_dir() / "sdh2-dsa"
FRAMES, REPEATS = 4000, 7
QUICK_FRAMES, QUICK_REPEATS = 400, 2


def real_frames(limit: int) -> tuple[np.ndarray, str] | None:
    """Up to ``limit`` real frames (uint16 [N, C]) from the .dsa recordings, or None."""
    try:
        from firmware_io.recordings.importers.dsa import read_dsa
    except ImportError:
        return None
    files = sorted(DATA.rglob("*.dsa")) if DATA.is_dir() else []
    chunks, names, total = [], [], 0
    for path in files:
        try:
            rec = read_dsa(path)
        except Exception as exc:  # a broken file only shrinks the sample
            print(f"skip {path.name}: {exc}", file=sys.stderr)
            continue
        if rec.frames.shape[1] != 486:
            continue
        chunks.append(rec.frames)
        names.append(str(path.relative_to(DATA)))
        total += len(rec.frames)
        if total >= limit:
            break
    if not chunks:
        return None
    frames = np.concatenate(chunks)[:limit]
    return frames, f"real SDH-2 recordings ({len(names)} .dsa files from {DATA}: {', '.join(names[:4])}...)"


def synthetic_frames(n: int, seed: int = 0) -> tuple[np.ndarray, str]:
    """Sparse contact blobs over zeros: synthetic, not measured."""
    rng = np.random.default_rng(seed)
    frames = np.zeros((n, 486), np.uint16)
    for i in range(n):
        start = int(rng.integers(0, 486 - 40))
        frames[i, start : start + 40] = rng.integers(0, 3500, 40)
    return frames, "synthetic frames (sparse random blobs; no real data found)"


def time_it(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def bench(frames: np.ndarray, rle: bool, repeats: int) -> dict:
    from firmware_io.wire.frames import decode_frame_payload, encode_frame_payload
    from firmware_io.wire.packets import encode_packet
    from firmware_io.wire.parser import StreamParser

    n, cells = frames.shape
    payloads = [encode_frame_payload(f, i, rle=rle) for i, f in enumerate(frames)]
    stream = b"".join(encode_packet(0, p) for p in payloads)
    decode = decode_frame_payload

    def payload_only() -> None:
        for p in payloads:
            decode(p, cells)

    def whole_stream() -> None:
        parser = StreamParser(cells)
        for start in range(0, len(stream), 4096):
            for packet in parser.feed(stream[start : start + 4096]):
                decode(packet.payload, cells)

    # check once that everything decodes to the source
    if not all(np.array_equal(decode(p, cells)[1], f) for p, f in zip(payloads[:50], frames[:50], strict=True)):
        raise RuntimeError("decoded frames differ from the encoded ones")
    result = {"frames": n, "mean_payload_bytes": float(np.mean([len(p) for p in payloads]))}
    for name, fn in (("payload", payload_only), ("stream", whole_stream)):
        secs = time_it(fn, repeats)
        per_frame = np.array(secs) / n
        result[name] = {
            "frames_per_s_median": n / statistics.median(secs),
            "us_per_frame_median": float(np.median(per_frame) * 1e6),
            "us_per_frame_min": float(per_frame.min() * 1e6),
            "repeats": repeats,
        }
    return result


def run(args) -> dict:
    n = args.frames or (QUICK_FRAMES if args.quick else FRAMES)
    repeats = args.repeats or (QUICK_REPEATS if args.quick else REPEATS)
    found = None if args.synthetic else real_frames(n)
    frames, source = found if found is not None else synthetic_frames(n)
    args.say(f"decode: {len(frames)} frames, {repeats} runs each, one core ...")
    result = {"source": source, "synthetic": found is None, "command": command_line("decode", args),
              "machine": machine_info(), "load_before": load_average()}
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_setaffinity") else None
    try:
        if cores:
            os.sched_setaffinity(0, {sorted(cores)[0]})  # one core, for this benchmark only
        result["rle"] = bench(frames, rle=True, repeats=repeats)
        result["raw"] = bench(frames, rle=False, repeats=repeats)
    finally:
        if cores:
            os.sched_setaffinity(0, cores)
    result["load_after"] = load_average()
    result["rle_frames_per_s"] = result["rle"]["payload"]["frames_per_s_median"]
    result["raw_frames_per_s"] = result["raw"]["payload"]["frames_per_s_median"]
    tag = " (synthetic)" if result["synthetic"] else ""
    lines = [
        f"# Frame decoding benchmark{tag}",
        "",
        f"Source: {source}. {len(frames)} frames of {frames.shape[1]} taxels, one core, median of {repeats} runs.",
        "",
        "| encoding | mean payload B | decode only: frames/s | us/frame | parser + CRC + decode: frames/s | us/frame |",
        "|---|---|---|---|---|---|",
    ]
    for enc in ("rle", "raw"):
        r = result[enc]
        lines.append(
            f"| {enc} | {r['mean_payload_bytes']:.0f} | {r['payload']['frames_per_s_median']:,.0f} | "
            f"{r['payload']['us_per_frame_median']:.1f} | {r['stream']['frames_per_s_median']:,.0f} | "
            f"{r['stream']['us_per_frame_median']:.1f} |"
        )
    write_results(args.out, "decode", result, lines)
    return result
