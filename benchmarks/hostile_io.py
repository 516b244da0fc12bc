"""The file, config and process attacks of ``./dev bench hostile`` (see benchmarks/hostile.py)."""

from __future__ import annotations

import json
import resource
import subprocess
import time
from collections import Counter
from pathlib import Path

from benchmarks.hostile_parts import cli, status_when
from trainer.bench.harness import spawn_daemon, stop_daemon


def _ends_in_one_line(done: subprocess.CompletedProcess, command: str, name: str) -> bool:
    lines = done.stderr.strip().splitlines()
    return done.returncode == 2 and len(lines) == 1 and lines[0].startswith(f"handover {command}: ") and name in lines[0]


def attack_recordings(work: Path, quick: bool) -> dict:
    """Each hostile recording through the reader, ``plot``, ``train`` and ``emulate`` (a .dsa: emulate)."""
    from benchmarks.hostile_recordings import write_all
    from firmware_io.recordings.importers import import_any
    from firmware_io.recordings.recording import RecordingError

    bomb = (64 << 20) if quick else (2 << 30)
    files = write_all(work / "recordings", bomb_bytes=bomb)
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    rows = {}
    for name, path in files.items():
        t0 = time.perf_counter()
        try:
            import_any(path)
            refused = False
        except RecordingError as exc:
            refused = str(exc).startswith(str(path)) and "\n" not in str(exc)
        row = {"bytes": path.stat().st_size, "load_refused_one_line": refused,
               "load_ms": round((time.perf_counter() - t0) * 1e3, 1)}
        commands = ("plot", "train", "emulate") if path.suffix == ".hrec" else ("emulate",)
        if quick and name not in ("deflate_bomb", "dsa_bzip2_bomb", "huge_shape", "deep_nesting"):
            commands = ()
        for command in commands:
            if command == "emulate":
                argv = ["emulate", "--pty", "--source", str(path), "--duration", "0.1"]
            elif command == "plot":
                argv = ["plot", str(path), "--out", str(work / "x.png")]
            else:
                data = work / f"train-{name}"
                data.mkdir()
                (data / path.name).symlink_to(path)
                argv = ["train", "--data", str(data), "--out", str(work / "report")]
            row[f"{command}_exit2_one_line"] = _ends_in_one_line(cli(argv, timeout=300), command, path.name)
        rows[name] = row
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss_before) / 1024
    failures = sum(not v for row in rows.values() for k, v in row.items() if k.endswith(("one_line",)))
    return {"files": rows, "deflate_bomb_inflates_to_bytes": bomb, "peak_rss_growth_mb": round(grown_mb, 1),
            "failures": failures}


BAD_NUMBERS = ("nan", "inf", "-inf", "1e300", "-1e300", "99999999999999999999", "-1")


def attack_config(work: Path) -> dict:
    """Every number of the config set to NaN, infinities and huge or negative values."""
    from runtime.config import RANGES, ConfigError, load_config

    count: Counter = Counter()
    path = work / "bad.toml"
    for key in RANGES:
        section, _, name = key.rpartition(".")  # a top-level key (realtime_priority) has no section
        for value in BAD_NUMBERS:
            path.write_text((f"[{section}]\n" if section else "") + f"{name} = {value}\n")
            try:
                load_config(path)
                count["accepted"] += 1
            except ConfigError as exc:
                good = str(exc).startswith(f"{key}:") and "\n" not in str(exc)
                count["refused_naming_the_key" if good else "refused_badly"] += 1
    for option in URL_OPTIONS:
        for value in BAD_NUMBERS:
            url = option.replace("X", value)
            if url == "sim://?speed=inf":  # documented: as fast as possible, like speed=max
                continue
            path.write_text(f'[device]\nurl = "{url}"\n')
            try:
                load_config(path)
                count["url_accepted"] += 1
            except ConfigError as exc:
                good = str(exc).startswith("device.url:") and "\n" not in str(exc)
                count["url_refused" if good else "refused_badly"] += 1
    return {"keys": len(RANGES), "values": list(BAD_NUMBERS), "tried": len(RANGES) * len(BAD_NUMBERS),
            "refused_naming_the_key": count["refused_naming_the_key"], "accepted": count["accepted"],
            "url_options": list(URL_OPTIONS), "url_tried": count["url_refused"] + count["url_accepted"],
            "url_refused": count["url_refused"], "url_accepted": count["url_accepted"],
            "failures": count["accepted"] + count["url_accepted"] + count["refused_badly"]}


URL_OPTIONS = ("tcp://10.0.0.2:13000?connect_timeout=X", "sim://?speed=X", "sim://?events=X", "sim://?seed=X",
               "serial:///dev/ttyUSB0?baud=X", "usb://0403:6001?baud=X")
"""Numbers inside the device URL (X is replaced); ``speed=inf`` means "as fast as possible" (like
``speed=max``) and is left out."""


def attack_daemon(work: Path) -> dict:
    """``handover run`` over the simulated hand while hostile models are dropped into its folder."""
    import onnx

    from benchmarks import hostile_models as H
    from benchmarks.hostile_models import write_model

    models, state = work / "daemon-models", work / "daemon-state"
    models.mkdir()
    state.mkdir()
    write_model(models, "good.onnx", H.valid(bias_class=1), mtime=time.time() - 100)
    config = state / "h.toml"
    config.write_text(f'health_file = "{state / "status.json"}"\n[device]\nurl = "sim://?events=6&speed=8"\n'
                      f'[model]\nfolder = "{models}"\npoll_interval_s = 0.05\n'
                      '[trigger]\nfraction = 0.02\nhysteresis = 0.01\n')
    unknown_op = onnx.load_from_string(H.valid())
    unknown_op.graph.node[0].op_type = "NoSuchOperator"
    hostile = {"ort-refuses.onnx": unknown_op.SerializeToString(), "ort-banner.onnx": H.ort_banner(), "nan.onnx": H.nan_scores(),
               "inf.onnx": H.inf_scores(), "label.onnx": H.label_out_of_range(), "slow.onnx": H.slow(40_000),
               **{f"mutant{i}.onnx": m for i, m in enumerate(H.mutations(H.valid(), 5, seed=5, max_flips=40))}}
    proc = spawn_daemon(config, stdout=subprocess.PIPE)
    try:
        time.sleep(1.0)
        for i, (name, data) in enumerate(hostile.items()):
            write_model(models, name, data, mtime=time.time() - 50 + i)
            time.sleep(0.3)
        status = status_when(state / "status.json", proc, lambda s: s.get("models_rejected", 0) >= len(hostile), 60.0)
        stop_daemon(proc, 10)
    finally:
        if proc.poll() is None:
            proc.kill()
        out, err = proc.communicate()
    lines = out.splitlines()
    non_json = sum(not _is_event(line) for line in lines)
    result = {"models_dropped": len(hostile), "models_rejected": status.get("models_rejected"),
              "events": sum('"type":"decision"' in line for line in lines), "non_json_stdout_lines": non_json,
              "exit_code": proc.returncode,
              "tracebacks": err.count("Traceback"), "frame_errors": status.get("frame_errors"),
              "still_serving": bool(status.get("model_id"))}
    result["failures"] = (non_json + result["tracebacks"] + int(proc.returncode != 0) + int(not result["still_serving"])
                          + int(result["models_rejected"] != len(hostile)))
    return result


def _is_event(line: str) -> bool:
    """A line of the event protocol (docs/EVENTS.md): a decision or a model announcement."""
    try:
        return json.loads(line).get("type") in ("decision", "model")
    except (ValueError, AttributeError):
        return False
