"""``./dev bench hostile``: the daemon and the tools under attack, with counts.

Four kinds of hostile input, each counted by outcome; a *failure* is any outcome the house
rules forbid (a crash, a traceback, more than one line, a non-JSON line on stdout, a frame the
sensor cannot send reaching the classifier, an out-of-range number accepted):

- models: attacks that pass the static contract and break the output contract on pressed pads,
  the same as sleepers that pass any warm-up, a 40,000-node graph over the time budget, and
  thousands of byte-mutated files;
- frames: real SDH-2 frames (../shared/data, else the simulated hand) with 2-bit errors, through
  the stream parser, the decoder and the plausibility check;
- recordings: a deflate bomb, huge declared shapes, deep nesting, bogus layouts, through
  ``Recording.load`` and the ``plot``/``train`` commands;
- config: NaN, infinities and huge values for every number of the config;
- the daemon as a process, with hostile models dropped into its folder while it serves;
- the world around it (benchmarks/hostile_world.py): a stdout nobody reads, silent DNS, other users
  on the control socket, a hanging model, rollbacks, half-written configs, crafted files, and more.

Writes results/hostile.json and .md.
"""

from __future__ import annotations

import json
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from benchmarks.hostile_models import write_model
from benchmarks.hostile_parts import folder_daemon, pressed_frames, serving
from trainer.measure import load_average, run_facts, write_results
from trainer.shared_data import default_data_dir

NAME = "hostile"


# -- models -------------------------------------------------------------------------------------
def attack_models(work: Path, quick: bool) -> dict:
    from benchmarks import hostile_models as H
    from runtime.model import ModelContractError, load_model
    from runtime.output_check import DEFAULT_BUDGET_FRACTION

    out: dict = {"warm_up": {}, "sleepers": {}}
    for name, build in H.RUNTIME_ATTACKS.items():
        path = write_model(work, f"{name}.onnx", build())
        load_model(path, warm_up=False)  # passes the static contract
        try:
            load_model(path)
            out["warm_up"][name] = "accepted"
        except ModelContractError:
            out["warm_up"][name] = "refused"
    for name in H.RUNTIME_ATTACKS:
        out["sleepers"][name] = sleeper_in_daemon(work / f"sleeper-{name}", name)
    path = write_model(work, "slow.onnx", H.slow(40_000))
    try:
        load_model(path, decision_budget=DEFAULT_BUDGET_FRACTION)  # the daemon's rule
        out["slow_40000_nodes"] = "accepted"
    except ModelContractError as exc:
        out["slow_40000_nodes"] = str(exc).removeprefix(f"model {path}: ")
    out["mutations"] = mutated_models(work, H.valid(), 300 if quick else 3000)
    out["failures"] = (sum(v != "refused" for v in out["warm_up"].values())
                       + sum(not s["handled"] for s in out["sleepers"].values())
                       + int(out["slow_40000_nodes"] == "accepted") + out["mutations"]["unnamed_errors"])
    return out


def sleeper_in_daemon(folder: Path, kind: str) -> dict:
    """A sleeper dropped over a serving model: taken out of service at its first real press?"""
    from benchmarks import hostile_models as H

    models = folder / "models"
    models.mkdir(parents=True)
    write_model(models, "old.onnx", H.valid(bias_class=1), mtime=time.time() - 100)
    events: list = []
    daemon = folder_daemon(models, folder / "status.json", on_event=events.append)
    write_model(models, "new.onnx", H.sleeper(kind))
    daemon.models.watcher.poll(require_stable=False)
    daemon._housekeeping(time.monotonic())
    for frame in pressed_frames(daemon.layout, range(120), lambda i: i % 60 < 20, int(H.SLEEPER_PEAK)):
        daemon.handle_frame(frame)
    after_restart = serving(folder_daemon(models, folder / "status.json"))
    h = daemon.health
    serves = serving(daemon)
    invalid = sum(not all(np.isfinite(list(e.scores.values()))) for e in events)
    return {"taken_out_of_service": h.models_quarantined, "serving_after": serves,
            "serving_after_restart": after_restart, "events": len(events), "invalid_events": invalid,
            "handled": h.models_quarantined == 1 and serves == "old.onnx" and after_restart == "old.onnx"
            and invalid == 0}


def mutated_models(work: Path, base: bytes, n: int) -> dict:
    """Byte-mutated copies of a valid model through the loader: refused with one line naming the
    file, or accepted (a mutation in a harmless byte); anything else is a failure."""
    from benchmarks.hostile_models import mutations
    from runtime.model import ModelContractError, load_model

    path = work / "mutant.onnx"
    outcome: Counter = Counter()
    for data in mutations(base, n, seed=19):
        path.write_bytes(data)
        try:
            load_model(path)
            outcome["accepted"] += 1
        except ModelContractError as exc:
            one_line = str(path) in str(exc) and "\n" not in str(exc)
            outcome["refused_one_line" if one_line else "unnamed_errors"] += 1
        except Exception:  # exactly what is being counted
            outcome["unnamed_errors"] += 1
    return {"n": n, "refused_one_line": outcome["refused_one_line"], "accepted": outcome["accepted"],
            "unnamed_errors": outcome["unnamed_errors"]}


# -- frames -------------------------------------------------------------------------------------
def source_frames(limit: int = 4000) -> tuple[np.ndarray, str]:
    """Real SDH-2 frames with contact where ../shared/data exists, else the simulated hand's."""
    from firmware_io.recordings.importers import find_sources, import_any

    shared = default_data_dir()
    if shared.is_dir():
        frames = []
        for path in find_sources(shared):
            if path.suffix != ".dsa":
                continue
            rec = import_any(path)
            frames.append(rec.frames[rec.frames.max(axis=1) > 0][:500])
            if sum(len(f) for f in frames) >= limit:
                return np.concatenate(frames)[:limit], f"real SDH-2 recordings ({shared})"
    from firmware_io.emulator.frame_source import load_source

    rec = load_source("sim", seed=0, events=8)
    return rec.frames[:limit], "simulated hand (synthetic)"


def attack_frames(n: int, seed: int = 0) -> dict:
    """``n`` frames (raw and RLE, alternating) each with two flipped bits, through parser, decoder
    and plausibility check, followed by an intact frame (so the parser resynchronises)."""
    from firmware_io.layout import SensorLayout
    from firmware_io.plausibility import FrameCheck
    from firmware_io.wire.errors import FrameDecodeError
    from firmware_io.wire.frames import decode_frame_payload, encode_frame
    from firmware_io.wire.parser import StreamParser

    frames, source = source_frames()
    layout = SensorLayout.sdh2()
    check = FrameCheck(layout)
    rng = np.random.default_rng(seed)
    count: Counter = Counter()
    for i in range(n):
        values = frames[i % len(frames)]
        rle = bool(i % 2)
        good = encode_frame(values, i, rle=rle)
        bad = bytearray(good)
        for bit in rng.choice((len(bad) - 3) * 8, size=2, replace=False):
            bad[3 + bit // 8] ^= 1 << (bit % 8)
        parser = StreamParser(layout.n_taxels)
        packets = parser.feed(bytes(bad) + good)  # the intact frame after it resynchronises the parser
        count["crc_rejected"] += parser.stats.crc_errors
        count["header_rejected"] += parser.stats.bad_headers
        for packet in (p for p in packets if p.payload != good[6:-2]):
            try:
                _, got = decode_frame_payload(packet.payload, layout.n_taxels)
            except FrameDecodeError:
                count["decode_rejected"] += 1
                continue
            if check.problem(got) is not None:
                count["implausible_dropped"] += 1
            elif np.array_equal(got, values):
                count["delivered_intact_taxels"] += 1  # the flips hit the time stamp or flags
            else:
                count["delivered_wrong_taxels"] += 1
                count["delivered_over_12bit"] += int(got.max() > 4095)
                count["delivered_on_missing_cells"] += int(got[check.dead].any())
    keys = ("crc_rejected", "header_rejected", "decode_rejected", "implausible_dropped", "delivered_intact_taxels",
            "delivered_wrong_taxels", "delivered_over_12bit", "delivered_on_missing_cells")
    out = {"n": n, "source": source, **{k: int(count[k]) for k in keys}}
    out["passed_crc"] = n - out["crc_rejected"] - out["header_rejected"]
    out["failures"] = out["delivered_over_12bit"] + out["delivered_on_missing_cells"]
    return out


# -- the run --------------------------------------------------------------------------------------
def run(args) -> dict:
    from benchmarks.hostile_io import attack_config, attack_daemon, attack_recordings
    from benchmarks.hostile_world import attack_world

    say = args.say
    load_before = load_average()
    t0 = time.perf_counter()
    n_frames = 5_000 if args.quick else 100_000
    with tempfile.TemporaryDirectory(prefix="handover-hostile-") as tmp:
        work = Path(tmp)
        say("hostile: models (warm-up, sleepers in the daemon, 40,000 nodes, mutations) ...")
        models = attack_models(work, args.quick)
        say(f"hostile: {n_frames} frames with 2-bit errors ...")
        frames = attack_frames(n_frames, seed=args.seed)
        say("hostile: recordings (deflate bomb, huge shapes, nesting, bogus layouts) through load, plot, train ...")
        recordings = attack_recordings(work, args.quick)
        say("hostile: config numbers ...")
        config = attack_config(work)
        say("hostile: the daemon process while hostile models are dropped ...")
        daemon = attack_daemon(work)
        world = attack_world(work, say)
    result = {"models": models, "frames": frames, "recordings": recordings, "config": config, "daemon": daemon,
              "world": world}
    result["hostile_failures"] = sum(part["failures"] for part in result.values())
    result.update(run_facts(NAME, args, load_before, t0))
    write_results(args.out, NAME, result, markdown(result))
    say(f"hostile: {result['hostile_failures']} failures; " + json.dumps(summary(result)))
    return result


def summary(res: dict) -> dict:
    """The counts a soak or a README cites."""
    m, f, r, c, d = (res[k] for k in ("models", "frames", "recordings", "config", "daemon"))
    return {"mutated_models": m["mutations"]["n"], "mutated_refused_one_line": m["mutations"]["refused_one_line"],
            "frames_2bit": f["n"], "frames_passed_crc": f["passed_crc"], "frames_implausible_dropped":
            f["implausible_dropped"], "frames_over_12bit_delivered": f["delivered_over_12bit"],
            "recordings": len(r["files"]), "config_values": c["tried"], "daemon_events": d["events"],
            "daemon_non_json_lines": d["non_json_stdout_lines"], "world_cases_held": res["world"]["held"],
            "world_cases_tried": res["world"]["tried"], "failures": res["hostile_failures"]}


def markdown(res: dict) -> list[str]:
    m, f, r, c, d = (res[k] for k in ("models", "frames", "recordings", "config", "daemon"))
    mu = m["mutations"]
    lines = [
        "# Hostile input", "",
        f"**{res['hostile_failures']} failures** (a crash, a traceback, more than one line, a non-JSON line on "
        "stdout, a frame the sensor cannot send reaching the classifier, an out-of-range number accepted).", "",
        "## Models", "",
        "| attack | outcome |", "|---|---|",
        *[f"| {k} (fires on pressed pads) | warm-up: {v} |" for k, v in m["warm_up"].items()],
        *[f"| sleeper {k} (fires on one exact value, passes warm-up) | taken out of service "
          f"{s['taken_out_of_service']}x, then {s['serving_after']} serves; after a restart {s['serving_after_restart']}"
          f"; {s['events']} events, {s['invalid_events']} invalid |" for k, s in m["sleepers"].items()],
        f"| 40,000 nodes | {m['slow_40000_nodes']} |",
        f"| {mu['n']} byte-mutated files | {mu['refused_one_line']} refused with one line naming the file, "
        f"{mu['accepted']} accepted (harmless bytes), {mu['unnamed_errors']} other errors |", "",
        f"## Frames with 2-bit errors ({f['source']})", "",
        f"{f['n']} frames (half raw, half RLE), two random bits flipped after the preamble: {f['crc_rejected']} "
        f"rejected by the CRC, {f['header_rejected']} by the header check, {f['passed_crc']} passed the CRC; of "
        f"those {f['decode_rejected']} failed to decode, **{f['implausible_dropped']} were dropped as implausible** "
        f"(above 12 bits or pressure on a missing cell), {f['delivered_intact_taxels']} reached the classifier with "
        f"intact taxels (the flips hit the time stamp or flags) and {f['delivered_wrong_taxels']} with wrong but "
        f"plausible taxels. Delivered above 12 bits: {f['delivered_over_12bit']}; on missing cells: "
        f"{f['delivered_on_missing_cells']}.", "",
        "## Recordings", "",
        "| file | bytes | read | plot | train | emulate |", "|---|---|---|---|---|---|",
        *[f"| {k} | {v['bytes']} | {'refused, one line' if v['load_refused_one_line'] else 'FAILED'} "
          f"({v['load_ms']} ms) | {_ok(v.get('plot_exit2_one_line'))} | {_ok(v.get('train_exit2_one_line'))} | "
          f"{_ok(v.get('emulate_exit2_one_line'))} |" for k, v in r["files"].items()],
        "", f"Each bomb inflates to {r['deflate_bomb_inflates_to_bytes']} bytes; peak memory of the reading "
        f"process grew by {r['peak_rss_growth_mb']} MB.", "",
        "## Config numbers", "",
        f"{c['keys']} numeric keys x {len(c['values'])} values ({', '.join(c['values'])}) = {c['tried']}: "
        f"{c['refused_naming_the_key']} refused naming the key, {c['accepted']} accepted. The same values as "
        f"options of the device URL ({', '.join(c['url_options'])}; X replaced, `speed=inf` is `max`): "
        f"{c['url_tried']} tried, {c['url_refused']} refused naming device.url, {c['url_accepted']} accepted.", "",
        "## The daemon as a process", "",
        f"`handover run` over the simulated hand (synthetic) while {d['models_dropped']} hostile models were dropped "
        f"into its folder: {d['models_rejected']} rejected, still serving: {d['still_serving']}, {d['events']} decisions "
        f"on stdout, {d['non_json_stdout_lines']} lines that are not events or model announcements, {d['tracebacks']} tracebacks, exit code "
        f"{d['exit_code']} after SIGTERM.", "",
        *world_markdown(res["world"]),
        f"Took {res['seconds']} s. {res['note']} Timings here (the 40,000-node decision, the hanging model's "
        "window) include that load.",
    ]
    return lines


def world_markdown(w: dict) -> list[str]:
    """The world's cases (benchmarks/hostile_world.py): one row each, what was tried and what came of it."""
    untried = [str(r["case"]) for r in w["cases"] if not r["tried"]]
    return [
        "## The world around the daemon", "",
        f"**{w['held']} of {w['tried']} cases held** (each with real pipes, sockets, subprocess daemons and ONNX "
        "files; the tests in tests/test_hostile_world.py run the same probes)"
        + (f"; not tried here: case {', '.join(untried)} (needs root or the ros extra)." if untried else "."), "",
        "| # | case | held | what was seen |", "|---|---|---|---|",
        *[f"| {r['case']} | {r['title']} | {'yes' if r['held'] else ('not tried' if not r['tried'] else 'NO')} | "
          + " / ".join(p["detail"].replace("|", "/") for p in r["probes"]) + " |" for r in w["cases"]],
        "",
    ]


def _ok(value: bool | None) -> str:
    return "-" if value is None else ("exit 2, one line" if value else "FAILED")
