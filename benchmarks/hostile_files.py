"""Files that eat the machine (issue 40: N4, N5, N6, N9, N10, N12, N13, D17 and their reruns), as cases of the hostile world.

Each attack runs ``handover`` in a child that reports its own peak memory and seconds; it holds when
the command ends in one line with exit 2 within ``LIMIT_S`` using less than ``LIMIT_MB``. A full disk
is injected in the child's zip writer (ENOSPC half-way through a save), as a small tmpfs needs root.
"""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np

from benchmarks.hostile_parts import ROOT, one_line

__all__ = ["files_that_eat", "full_disk_record"]

LIMIT_S, LIMIT_MB = 5.0, 500.0
MEASURED = """import json, sys, time
{prelude}
from runtime.cli import main
t = time.monotonic()
rc = main(sys.argv[1:])
print(json.dumps({{"rc": rc, "s": time.monotonic() - t,
                  "mb": int(open("/proc/self/status").read().split("VmHWM:")[1].split()[0]) / 1024}}), file=sys.stderr)
"""
FULL_DISK = """import errno, zipfile
real, saves = zipfile.ZipFile.writestr, []
def writestr(self, info, data, *a, **kw):
    name = getattr(info, "filename", info)
    saves.append(name == "header.json")
    if sum(saves) > 2 and name == "frames.npy":
        real(self, info, data[: len(data) // 2], *a, **kw)
        raise OSError(errno.ENOSPC, "No space left on device")
    return real(self, info, data, *a, **kw)
zipfile.ZipFile.writestr = writestr"""


def _measured(argv: list[str], prelude: str = "") -> tuple[dict, str]:
    """``handover ARGV`` in a child: its exit code, seconds and peak MB, and its other stderr lines."""
    done = subprocess.run([sys.executable, "-c", MEASURED.format(prelude=prelude), *argv], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)
    *said, last = done.stderr.strip().splitlines() or ["{}"]
    try:
        return json.loads(last), "\n".join(said)
    except ValueError:
        return {"rc": done.returncode}, done.stderr[-300:]


def _script(head: dict, events: list[dict]) -> str:
    return "\n".join(json.dumps(r, separators=(",", ":")) for r in [head, *events]) + "\n"


def _hostile_files(work: Path) -> dict[str, tuple[list[str], str]]:
    """name -> (handover argv, what its one line must say)."""
    from firmware_io.layout import SensorLayout
    from firmware_io.recordings.recording import Recording, Trial
    from firmware_io.sim import simulate_protocol

    head = {"type": "script", "protocol": 1, "started": True, "ended": False, "source": "", "synthetic": True,
            "clock_start_ms": 0, "loop_ms": 1, "frames": 1, "frame_ms": [0]}
    one = {"type": "scripted", "event": 1, "onset_frame": 0, "action": "pull", "subject": "s1", "object": "ball",
           "pose": "up", "first_frame": 0, "last_frame": 0, "time_s": None}
    wide = {**head, "loop_ms": None, "frames": 3, "frame_ms": [0, 31, 62]}
    loop = {**head, "loop_ms": 500, "frames": 500, "frame_ms": list(range(500))}
    spans = {**head, "loop_ms": None, "frames": 853, "frame_ms": list(range(0, 853 * 32, 32))}
    scripts = {"score bomb (500 ms loop, 500 events, decisions 99,998 ms apart)":
               (_script(loop, [{**one, "event": k, "first_frame": k - 1, "onset_frame": k - 1, "last_frame": k - 1}
                               for k in range(1, 501)]), "passes of the script"),
               "101,091 events on the same frames, under 16 MiB":
               (_script(spans, [{**one, "event": k, "last_frame": 852} for k in range(1, 101_092)]),
                "more than any session handover scripts"),
               "overlapping events": (_script(wide, [{**one, "last_frame": 1}, {**one, "event": 2, "last_frame": 2}]),
                                      "starts before event 1 ends"),
               "an ESC in an action": (_script(wide, [{**one, "action": "pu\u001b[2Jll"}]), "printable characters"),
               "100,000 nested brackets": ("[" * 100_000 + "]" * 100_000 + "\n", "not JSON lines"),
               "descending frame_ms": (_script({**wide, "frame_ms": [0, 62, 31]}, [one]), "goes back in time"),
               "first frame after last": (_script(wide, [{**one, "first_frame": 2, "last_frame": 1}]), "after its last"),
               "negative frame": (_script(wide, [{**one, "first_frame": -1}]), "whole frames"),
               "onset past the end": (_script(wide, [{**one, "onset_frame": 3}]), "whole frames"),
               "fractional frame": (_script(wide, [{**one, "last_frame": 1.5}]), "whole frames"),
               "1 MB action name": (_script(wide, [{**one, "action": "x" * (1 << 20)}]), "action must be a name")}
    events = work / "events.jsonl"
    events.write_text("".join(json.dumps({"type": "decision", "class": "pull", "device_time_ms": t}) + "\n"
                              for t in (0, 99_998)))
    out = {}
    for i, (name, (text, says)) in enumerate(scripts.items()):
        (work / f"s{i}.script").write_text(text)
        out[name] = (["score", str(events), str(work / f"s{i}.script")], says)
    out["/dev/zero as the script"] = (["score", str(events), "/dev/zero"], "not a regular file")
    good = work / "good.script"
    good.write_text(scripts["descending frame_ms"][0].replace("[0,62,31]", "[0,31,62]"))
    out["/dev/zero as the events"] = (["score", "/dev/zero", str(good)], "MiB of event")
    (work / "daemon.log").write_text("12:00:00 handover: connected\nframes at 31.2 Hz\n")
    out["the daemon's log as the events"] = (["score", str(work / "daemon.log"), str(good)], "is an event line")
    (work / "nested.jsonl").write_text("[" * 100_000 + "]" * 100_000 + "\n")
    out["100,000 nested brackets as the events"] = (["score", str(work / "nested.jsonl"), str(good)], "is an event line")
    out["the script as the events"] = (["score", str(good), str(good)], "not event lines")

    layout = SensorLayout.sdh2()
    n = (1 << 30) // (2 * layout.n_taxels)  # 1 GiB of frames, within the per-file limit, deflated to a few MB
    deflated = work / "deflated" / "subject_z.hrec"
    deflated.parent.mkdir()
    with zipfile.ZipFile(deflated, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("header.json", json.dumps({"format": "handover-recording", "version": 1, "n_frames": n,
                                               "n_taxels": layout.n_taxels, "layout": layout.to_dict(),
                                               "trials": [], "meta": {}}))
        with zf.open("frames.npy", "w", force_zip64=True) as fh:
            np.lib.format.write_array_header_1_0(fh, {"descr": "<u2", "fortran_order": False,
                                                      "shape": (n, layout.n_taxels)})
            for at in range(0, n * layout.n_taxels * 2, 1 << 20):
                fh.write(bytes(min(1 << 20, n * layout.n_taxels * 2 - at)))
    out["a deflated .hrec of 1 GiB of frames"] = (["train", "--data", str(deflated.parent), "--out",
                                                   str(work / "r0")], "is compressed")
    rec = simulate_protocol(seed=0, n_subjects=1, runs=1)[0]
    for name, change, says in (("a trial with run 10**30", {"run": 10**30}, "outside 0.."),
                               ("a 4 MB subject id", {"subject": "s" * (4 << 20)}, "1 to 64 printable characters"),
                               ("an ESC in a subject id", {"subject": "s1\x1b[2J"}, "printable characters")):
        folder = work / f"data{len(out)}"
        bad = Recording(rec.layout, rec.frames, rec.timestamps, list(rec.trials), rec.meta)
        bad.trials[0] = Trial(**{**rec.trials[0].to_dict(), **change})  # refused by save: written as load sees it
        folder.mkdir()
        _save_unchecked(bad, folder / "subject_s1.hrec")
        out[name] = (["train", "--data", str(folder), "--out", str(work / f"r{len(out)}")], says)
    dsa = work / "frame_bomb.dsa"
    _frame_bomb(dsa, 1_000_000)
    out["a .dsa frame bomb (a million one-run frames)"] = (["emulate", "--pty", "--source", str(dsa), "--duration",
                                                            "0.1"], "declares 1000000 frames")
    return out


def _save_unchecked(rec, path: Path) -> None:
    from firmware_io.recordings import recording as R

    problem, R.Recording.problem = R.Recording.problem, lambda self: None
    try:
        rec.save(path)
    finally:
        R.Recording.problem = problem


def _frame_bomb(path: Path, n: int) -> None:
    from firmware_io.layout import SensorLayout

    layout = SensorLayout.sdh2()
    head = ['<?xml version="1.0"?>', "<root>", '<sensor name="">', f"<num_matrices>{layout.n_matrices}</num_matrices>"]
    for m in layout.matrices:
        mask = "\n".join("".join("1" if c else "0" for c in row) for row in m.mask)
        head += [f'<matrix index="{m.index}"><cells_x>{m.cells_x}</cells_x><cells_y>{m.cells_y}</cells_y>'
                 f"<static_mask>\n{mask}\n</static_mask></matrix>"]
    frame = b"<frame><time_stamp>1</time_stamp><frame_data>C3F30000</frame_data></frame>\n"
    path.write_bytes("\n".join([*head, "</sensor>", "<data>", ""]).encode() + frame * n + b"</data></root>\n")


def files_that_eat(work: Path) -> dict:
    """Every hostile file: one line, exit 2, within ``LIMIT_S`` (beyond the command's own start-up: ``train``
    takes seconds to refuse a missing folder on a busy machine) and ``LIMIT_MB`` (the child's peak, which on
    Linux includes what this process held when it forked: an upper bound)."""
    startup, _ = _measured(["train", "--data", str(work / "missing"), "--out", str(work / "r")])
    failed, worst_s, worst_mb = [], 0.0, 0.0
    for name, (argv, says) in _hostile_files(work).items():
        got, said = _measured(argv)
        took = got.get("s", 99.0) - (startup.get("s", 0.0) if argv[0] == "train" else 0.0)
        worst_s, worst_mb = max(worst_s, took), max(worst_mb, got.get("mb", 9e9))
        if not (got.get("rc") == 2 and one_line(said, says) and took < LIMIT_S and got.get("mb", 9e9) < LIMIT_MB):
            failed.append(f"{name}: {got} {said[-120:]!r}")
    return {"held": not failed, "detail": f"worst {worst_s:.1f} s beyond start-up (train's: {startup.get('s', 0):.1f} "
            f"s), {worst_mb:.0f} MB" + (f"; not held: {'; '.join(failed)}" if failed else "")}


def full_disk_record(work: Path) -> dict:
    """``record`` on a disk that fills at the third save says what was saved and to run again, leaves no
    temp file, and resumes when space returns; a temp file a killed save left is removed by the resume."""
    base = ["record", "--device", "subject://?seed=3&speed=max", "--subject", "s1", "--out", str(work), "--poses",
            "down", "--objects", "ball", "--runs", "1", "--trial-seconds", "2", "--gap", "0", "--countdown", "0",
            "--quiet", "--idle-minutes", "0", "--auto", "--no-look"]
    got, said = _measured(base, FULL_DISK)
    told = got.get("rc") == 2 and one_line(said, "2 trials saved in", "run the same command again to resume")
    (work / ".subject_s1.hrec.k2_9xq0a.tmp").write_bytes(b"PK half a recording")  # a kill -9 mid-save
    again, _ = _measured(base)
    left = sorted(p.name for p in work.iterdir())
    held = told and again.get("rc") == 0 and left == ["subject_s1.hrec"]
    return {"held": held, "detail": f"full disk: {said[-160:]!r}; resumed: exit {again.get('rc')}; files: {left}"}
