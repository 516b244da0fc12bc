"""Importers: every real .dsa and .bag in ../shared/data/sdh2-dsa, plus synthetic and broken inputs."""

from __future__ import annotations

import bz2
import functools
import struct
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from firmware_io.layout import SensorLayout
from firmware_io.recordings.importers import find_sources, import_any, read_dsa, read_rosbag
from firmware_io.recordings.recording import Recording, RecordingError
from runtime.cli import main as handover
from tests.conftest import SDH2_DATA, bag_files, dsa_files, real_data_dir
from tests.memory import PEAK_MB

SDH2 = SensorLayout.sdh2()


def _ids(paths: list[Path]) -> list[str]:
    return [str(p.relative_to(SDH2_DATA)) for p in paths]


DSA = dsa_files()
BAGS = bag_files()
# with no data folder each parameter list holds one None, and the test skips with the reason
DSA_PARAMS = pytest.mark.parametrize("path", DSA or [None], ids=_ids(DSA) if DSA else ["no-data"])
BAG_PARAMS = pytest.mark.parametrize("path", BAGS or [None], ids=_ids(BAGS) if BAGS else ["no-data"])


@functools.cache
def imported(path: Path) -> Recording:
    """Each real file is parsed once per test session (several tests look at it)."""
    return import_any(path)


def real(path: Path | None, kind: str) -> Recording:
    real_data_dir()
    if path is None:
        pytest.skip(f"no {kind} files under {SDH2_DATA}")
    return imported(path)


def check_real_recording(rec: Recording) -> None:
    assert rec.layout.n_taxels == 486
    assert [(m.cells_x, m.cells_y) for m in rec.layout.matrices] == [(6, 14), (6, 13)] * 3
    assert np.array_equal(rec.layout.static_mask(), SDH2.static_mask())
    assert rec.frames.dtype == np.uint16 and rec.frames.shape[1] == 486
    assert rec.n_frames > 0
    assert int(rec.frames.max()) <= 4095
    assert np.all(np.diff(rec.timestamps) > 0)
    assert rec.timestamps[0] == 0.0
    # the DSACON32m reports 0 where a distal pad has no taxel
    assert not rec.frames[:, ~SDH2.static_mask()].any()


# -- real data -------------------------------------------------------------------------------


@DSA_PARAMS
def test_every_real_dsa_file(path):
    rec = real(path, ".dsa")
    check_real_recording(rec)
    assert rec.meta["source_format"] == "dsa-konqueror"
    interval = rec.sample_interval()
    # about 31 Hz, or the faster partial-readout rate of frequency_analysis / masked files,
    # or one frame every 3 s for the long noise-over-temperature log
    assert 0.005 < interval < 0.040 or "noise" in path.name


@BAG_PARAMS
def test_every_real_bag(path):
    rec = real(path, ".bag")
    check_real_recording(rec)
    assert rec.meta["source_format"] == "ros1-bag"
    assert rec.meta["topic"] == "/dsa_controller/tactile_data"
    assert rec.meta["time_source"] == "header"
    assert rec.sample_interval() == pytest.approx(1 / 31.25, rel=0.05)


def _reference_dsa_decode(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A slow, independent decoder (full XML parse, one token at a time) to check the fast one."""
    root = ET.fromstring(bz2.decompress(path.read_bytes()))
    stamps, frames = [], []
    for frame in root.iter("frame"):
        stamps.append(int(frame.findtext("time_stamp")))
        hexdata = "".join(frame.findtext("frame_data").split())
        values: list[float] = []
        for k in range(0, len(hexdata), 8):
            (v,) = struct.unpack(">f", bytes.fromhex(hexdata[k : k + 8]))
            values.extend([0.0] * int(-v) if v < 0 else [v])
        frames.append(values)
    return np.array(stamps), np.array(frames)


def test_fast_dsa_decoder_matches_a_reference_decoder():
    real_data_dir()
    if not DSA:
        pytest.skip("no .dsa files")
    for path in sorted(DSA, key=lambda p: p.stat().st_size)[:3]:
        stamps, frames = _reference_dsa_decode(path)
        rec = imported(path)
        assert np.array_equal(rec.frames, frames.astype(np.uint16))
        assert np.allclose(rec.timestamps, (stamps - stamps[0]) / 1000.0)


def test_truncated_real_dsa_file(tmp_path):
    real_data_dir()
    if not DSA:
        pytest.skip("no .dsa files")
    source = DSA[0]
    data = source.read_bytes()
    for name, cut in (("half.dsa", len(data) // 2), ("header_only.dsa", 200), ("empty.dsa", 0)):
        bad = tmp_path / name
        bad.write_bytes(data[:cut])
        with pytest.raises(RecordingError) as info:
            read_dsa(bad)
        assert str(bad) in str(info.value)


def test_find_sources():
    real_data_dir()
    sources = list(find_sources(SDH2_DATA))
    assert set(sources) == set(DSA) | set(BAGS)


# -- synthetic .dsa files --------------------------------------------------------------------


def _hex_tokens(values: np.ndarray) -> str:
    """DSA-Konqueror's frame_data: runs of zeros as one negative token, others as they are."""
    tokens: list[float] = []
    run = 0
    for v in values:
        if v == 0:
            run += 1
            continue
        if run:
            tokens.append(-run)
            run = 0
        tokens.append(float(v))
    if run:
        tokens.append(-run)
    return np.asarray(tokens, dtype=">f4").tobytes().hex().upper()


def write_dsa(path: Path, frames, stamps_ms, layout: SensorLayout = SDH2, frame_count=None, compress=True) -> Path:
    """A minimal DSA-Konqueror file in the same structure as the real ones (synthetic data)."""
    lines = ['<?xml version="1.0" encoding="utf-8"?>', "<root>", '  <sensor name="">']
    lines.append(f"    <num_matrices>{layout.n_matrices}</num_matrices>")
    for m in layout.matrices:
        mask = "\n".join("".join("1" if c else "0" for c in row) for row in m.mask)
        lines += [
            f'    <matrix index="{m.index}" name="">',
            f"      <cells_x>{m.cells_x}</cells_x>",
            f"      <cells_y>{m.cells_y}</cells_y>",
            f"      <texel_width>{m.texel_width}</texel_width>",
            f"      <texel_height>{m.texel_height}</texel_height>",
            f"      <matrix_center_x>{m.center[0]}</matrix_center_x>",
            f"      <matrix_center_y>{m.center[1]}</matrix_center_y>",
            f"      <matrix_center_z>{m.center[2]}</matrix_center_z>",
            f"      <fullscale>{m.fullscale:g}</fullscale>",
            f"      <static_mask>\n{mask}\n      </static_mask>",
            "    </matrix>",
        ]
    lines += [
        "  </sensor>",
        "  <data>",
        f"    <frame_count>{len(frames) if frame_count is None else frame_count}</frame_count>",
    ]
    for i, (values, t) in enumerate(zip(frames, stamps_ms, strict=True)):
        tokens = _hex_tokens(np.asarray(values))
        wrapped = "\n        ".join(tokens[k : k + 64] for k in range(0, len(tokens), 64))
        lines += [
            f'    <frame index="{i}">',
            f"      <time_stamp>{t}</time_stamp>",
            f"      <frame_data>\n        {wrapped}\n      </frame_data>",
            "    </frame>",
        ]
    lines += ["  </data>", "</root>", ""]
    data = "\n".join(lines).encode()
    path.write_bytes(bz2.compress(data) if compress else data)
    return path


def synthetic_frames(n: int = 40, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    frames = np.zeros((n, 486), np.int64)
    contact = rng.integers(0, 486, size=(n, 30))
    np.put_along_axis(frames, contact, rng.integers(1, 4096, size=(n, 30)), axis=1)
    frames[:, ~SDH2.static_mask()] = 0
    return frames


def test_synthetic_dsa_round_trip(tmp_path):
    frames = synthetic_frames()
    stamps = 1_400_000_000_000 + np.cumsum(np.full(len(frames), 31))
    for compress in (True, False):
        rec = read_dsa(write_dsa(tmp_path / f"s{compress}.dsa", frames, stamps, compress=compress))
        assert np.array_equal(rec.frames, frames)
        assert np.allclose(rec.timestamps, np.arange(len(frames)) * 0.031)
        assert rec.meta["time_origin_unix"] == pytest.approx(stamps[0] / 1000)
        check_real_recording(rec)


def test_dsa_layout_comes_from_the_header(tmp_path):
    layout = SensorLayout.sdh2().subset("1,3")  # two distal pads only
    frames = np.zeros((3, layout.n_taxels), np.int64)
    frames[:, 100] = 17
    rec = read_dsa(write_dsa(tmp_path / "two.dsa", frames, [0, 30, 60], layout=layout))
    assert rec.layout.n_taxels == 156 and rec.layout.static_mask().sum() == 136
    assert rec.frames[:, 100].tolist() == [17, 17, 17]


def test_dsa_duplicate_and_out_of_order_frames_are_dropped_and_counted(tmp_path):
    frames = synthetic_frames(6)
    frames = np.concatenate([frames[:3], frames[2:3], frames[3:]])  # frame 2 logged twice
    stamps = [0, 31, 62, 62, 93, 80, 124]  # then one frame stamped back in time
    rec = read_dsa(write_dsa(tmp_path / "dup.dsa", frames, stamps))
    assert rec.n_frames == 5
    assert rec.meta["duplicate_frames_dropped"] == 1
    assert rec.meta["out_of_order_frames_dropped"] == 1
    assert np.allclose(rec.timestamps, [0, 0.031, 0.062, 0.093, 0.124])


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda f: f.__setitem__((1, 5), 4096), "outside 0..4095"),
        (lambda f: f.__setitem__((2, 7), 12.5), "whole ADC count"),
    ],
)
def test_dsa_bad_values(tmp_path, mutate, match):
    frames = synthetic_frames(4).astype(np.float64)
    mutate(frames)
    path = write_dsa(tmp_path / "bad.dsa", frames, [0, 31, 62, 93])
    with pytest.raises(RecordingError, match=match) as info:
        read_dsa(path)
    assert str(path) in str(info.value)


def _edit(path: Path, old: bytes, new: bytes, count: int = 1) -> Path:
    text = bz2.decompress(path.read_bytes())
    assert old in text
    path.write_bytes(bz2.compress(text.replace(old, new, count)))
    return path


def test_dsa_structural_errors(tmp_path):
    frames = synthetic_frames(4)
    frames[:, -1] = 5  # the last token is a value, so dropping it shortens the frame
    stamps = [0, 31, 62, 93]

    def fresh(name: str) -> Path:
        return write_dsa(tmp_path / name, frames, stamps)

    cases = [
        (write_dsa(tmp_path / "count.dsa", frames, stamps, frame_count=9), "header says 9 frames"),
        (
            _edit(fresh("short.dsa"), b"40A00000\n      </frame_data>", b"\n      </frame_data>"),
            "frame 0 has 485 taxels",
        ),
        (_edit(fresh("hex.dsa"), b"<frame_data>\n        ", b"<frame_data>\n        ZZZZZZZZ"), "not hex"),
        (_edit(fresh("odd.dsa"), b"<frame_data>\n        ", b"<frame_data>\n        ABC"), "hex digits"),
        (_edit(fresh("stamp.dsa"), b"<time_stamp>31<", b"<time_stamp>3x1<"), "malformed"),
        (_edit(fresh("noend.dsa"), b"  </data>\n</root>", b""), "truncated"),
        (_edit(fresh("mask.dsa"), b"011110", b"01111"), "static mask"),
        (_edit(fresh("nmat.dsa"), b"<num_matrices>6", b"<num_matrices>7"), "7 matrices"),
        (write_dsa(tmp_path / "none.dsa", frames[:0], []), "no frames"),
    ]
    for path, match in cases:
        with pytest.raises(RecordingError, match=match) as info:
            read_dsa(path)
        assert str(path) in str(info.value), path


def test_foreign_files_are_refused(tmp_path):
    text = tmp_path / "notes.dsa"
    text.write_text("hello\n")
    random = tmp_path / "random.dsa"
    random.write_bytes(np.random.default_rng(0).bytes(5000))
    other_xml = tmp_path / "other.dsa"
    other_xml.write_bytes(bz2.compress(b'<?xml version="1.0"?><root><something/></root>'))
    for path, match in ((text, "neither bzip2 nor XML"), (random, "neither"), (other_xml, "not a DSA")):
        with pytest.raises(RecordingError, match=match) as info:
            read_dsa(path)
        assert str(path) in str(info.value)
    with pytest.raises(RecordingError, match="no such file"):
        read_dsa(tmp_path / "missing.dsa")
    with pytest.raises(RecordingError):
        read_rosbag(text.rename(tmp_path / "notes.bag"))


# -- ROS 2 bags ------------------------------------------------------------------------------


def write_ros2_bag(
    folder: Path,
    frames: np.ndarray,
    stamps_ns,
    header_stamps: bool = True,
    storage: str = "sqlite3",
    topic: str = "/dsa_controller/tactile_data",
) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer

    from firmware_io.recordings.importers.rosbag import MATRIX_MSGTYPE, MSGTYPE, typestore

    store = typestore()
    Sensor, Matrix = store.types[MSGTYPE], store.types[MATRIX_MSGTYPE]
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(folder, version=8, storage_plugin=plugin) as writer:
        conn = writer.add_connection(topic, MSGTYPE, typestore=store)
        for values, ns in zip(frames, stamps_ns, strict=True):
            stamp = Time(sec=int(ns // 10**9), nanosec=int(ns % 10**9)) if header_stamps else Time(sec=0, nanosec=0)
            mats = [
                Matrix(
                    matrix_id=m.index,
                    cells_x=m.cells_x,
                    cells_y=m.cells_y,
                    tactile_array=np.asarray(values[SDH2.matrix_slice(m.index)], dtype=np.int16),
                )
                for m in reversed(SDH2.matrices)  # any order on the wire of ROS: matrix_id decides
            ]
            msg = Sensor(header=Header(stamp=stamp, frame_id=""), tactile_matrix=mats)
            writer.write(conn, int(ns) + 1_000_000, store.serialize_cdr(msg, MSGTYPE))
    return folder


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_ros2_bag_round_trip(tmp_path, storage):
    pytest.importorskip("rosbags")
    frames = synthetic_frames(25)
    stamps = 1_416_316_996_000_000_000 + np.arange(25) * 32_000_000
    folder = write_ros2_bag(tmp_path / "bag", frames, stamps, storage=storage)
    rec = read_rosbag(folder)
    assert np.array_equal(rec.frames, frames)
    assert np.allclose(rec.timestamps, np.arange(25) * 0.032)
    assert rec.meta["source_format"] == "ros2-bag" and rec.meta["time_source"] == "header"
    check_real_recording(rec)
    # import_any finds it from the folder or from the storage file inside
    inner = next(p for p in folder.iterdir() if p.suffix in (".db3", ".mcap"))
    assert np.array_equal(import_any(inner).frames, frames)


def test_ros2_bag_without_header_stamps_uses_bag_time(tmp_path):
    pytest.importorskip("rosbags")
    frames = synthetic_frames(5)
    stamps = np.arange(5) * 30_000_000 + 10**18
    rec = read_rosbag(write_ros2_bag(tmp_path / "bag", frames, stamps, header_stamps=False))
    assert rec.meta["time_source"] == "bag"
    assert np.allclose(rec.timestamps, np.arange(5) * 0.03)


def test_ros2_bag_topic_errors(tmp_path):
    pytest.importorskip("rosbags")
    folder = write_ros2_bag(tmp_path / "bag", synthetic_frames(3), np.arange(3) * 10**7 + 10**18, topic="/tactile")
    assert read_rosbag(folder, topic="/tactile").n_frames == 3
    with pytest.raises(RecordingError, match=r"no topic '/nope'.*/tactile") as info:
        read_rosbag(folder, topic="/nope")
    assert str(folder) in str(info.value)
    with pytest.raises(RecordingError, match=r"metadata\.yaml"):
        read_rosbag(tmp_path)


# -- import_any and the command --------------------------------------------------------------


def test_import_any_dispatch(tmp_path):
    frames = synthetic_frames(5)
    dsa = write_dsa(tmp_path / "a.dsa", frames, np.arange(5) * 31)
    assert np.array_equal(import_any(dsa).frames, frames)
    hrec = import_any(dsa).save(tmp_path / "a.hrec")
    assert np.array_equal(import_any(hrec).frames, frames)
    unknown = tmp_path / "a.csv"
    unknown.write_text("1,2,3\n")
    with pytest.raises(RecordingError, match="unknown recording format"):
        import_any(unknown)
    with pytest.raises(RecordingError, match="no such file"):
        import_any(tmp_path / "missing.xyz")


def test_import_command(tmp_path, capsys):
    src = tmp_path / "src"
    (src / "x").mkdir(parents=True)
    (src / "y").mkdir()
    frames = synthetic_frames(10)
    write_dsa(src / "x" / "A1.dsa", frames, np.arange(10) * 32)
    write_dsa(src / "y" / "A1.dsa", frames, np.arange(10) * 32)
    (src / "broken.dsa").write_bytes(b"BZh91AY&SY broken")
    out = tmp_path / "out"
    code = handover(["import", str(src), "--out", str(out), "--pads", "distal"])
    captured = capsys.readouterr()
    assert code == 1
    assert sorted(p.name for p in out.iterdir()) == ["x-A1.hrec", "y-A1.hrec"]
    assert captured.out.count("10 frames") == 2 and "31.2 Hz" in captured.out
    errors = captured.err.strip().splitlines()
    assert errors[0].startswith("handover import: ") and "broken.dsa" in errors[0]
    assert errors[-1] == "handover import: 1 of 3 sources failed"
    rec = Recording.load(out / "x-A1.hrec")
    assert rec.layout.n_taxels == 234 and rec.meta["pads"] == [1, 3, 5]
    assert np.array_equal(rec.frames, frames[:, SDH2.columns("distal")])

    assert handover(["import", str(src / "x" / "A1.dsa"), "--out", str(out)]) == 0
    assert Recording.load(out / "A1.hrec").layout.n_taxels == 486
    capsys.readouterr()
    assert handover(["import", str(src), "--out", str(out), "--pads", "palm"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("handover import: unknown pad selection")
    assert handover(["import", str(src / "x" / "A1.dsa"), "--out", str(out), "--pads", "7"]) == 1
    assert "no matrix 7" in capsys.readouterr().err
    assert handover(["import", str(tmp_path / "missing.dsa"), "--out", str(out)]) == 1
    assert "missing.dsa: no such file" in capsys.readouterr().err


def test_damaged_real_bag(tmp_path):
    pytest.importorskip("rosbags")
    real_data_dir()
    if not BAGS:
        pytest.skip("no .bag files")
    data = BAGS[0].read_bytes()
    half = tmp_path / "half.bag"
    half.write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match="not a readable ROS bag") as info:
        read_rosbag(half)
    assert str(half) in str(info.value)
    # bags have no checksums: a damaged value is caught only when it cannot be a 12-bit reading
    rng = np.random.default_rng(1)
    damaged = tmp_path / "damaged.bag"
    refused = 0
    for _ in range(8):
        buf = bytearray(data)
        pos = int(rng.integers(len(buf) // 4, 3 * len(buf) // 4))
        buf[pos : pos + 8] = b"\xff\x7f" * 4
        damaged.write_bytes(bytes(buf))
        try:
            rec = read_rosbag(damaged)
        except RecordingError as exc:
            assert str(damaged) in str(exc)
            refused += 1
        else:
            check_real_recording(rec)
    assert refused > 0


def test_missing_rosbags_gives_the_install_hint(monkeypatch, tmp_path):
    import sys

    bag = tmp_path / "x.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n")
    monkeypatch.setitem(sys.modules, "rosbags.typesys", None)
    with pytest.raises(RecordingError, match=r"tactile-handover\[train\]"):
        read_rosbag(bag)


def test_importing_another_file_of_the_same_name_into_a_folder_keeps_the_first(tmp_path, capsys):
    """Two sessions' A.dsa imported one after the other into one folder (idle, say): the second
    lands beside the first; importing the same file again (now as idle) replaces it, nothing doubled."""
    frames = synthetic_frames(10)
    (tmp_path / "room").mkdir()
    (tmp_path / "hot").mkdir()
    write_dsa(tmp_path / "room" / "A.dsa", frames, np.arange(10) * 32)
    write_dsa(tmp_path / "hot" / "A.dsa", frames[::-1].copy(), np.arange(10) * 32)
    out = tmp_path / "out"
    assert handover(["import", str(tmp_path / "room" / "A.dsa"), "--out", str(out), "--idle", "quiet"]) == 0
    assert handover(["import", str(tmp_path / "hot" / "A.dsa"), "--out", str(out), "--idle", "quiet"]) == 0
    assert f"-> {out / 'A-2.hrec'}" in capsys.readouterr().out
    assert np.array_equal(Recording.load(out / "A.hrec").frames, frames)
    assert np.array_equal(Recording.load(out / "A-2.hrec").frames, frames[::-1])
    assert handover(["import", str(tmp_path / "room" / "A.dsa"), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["A-2.hrec", "A.hrec"]
    assert "idle_stretches" not in Recording.load(out / "A.hrec").meta


def test_a_frame_bomb_is_refused_before_its_frames_are_cut_out(tmp_path):
    """A million frames of one zero run each (75 MB of XML, 486 million values) was refused only after
    every frame was cut out into a list: 1.26 GB peak for a 6.9 MB bzip2 file. Counted in place now:
    the child's peak is the file's text and the interpreter, not a multiple of it."""
    import json
    import os
    import subprocess
    import sys

    path = write_dsa(tmp_path / "bomb.dsa", np.zeros((1, 486), np.int64), [0], compress=False)
    text = path.read_bytes()
    frame = b"<frame><time_stamp>1</time_stamp><frame_data>C3F30000</frame_data></frame>\n"
    path.write_bytes(text[: text.index(b"<frame_count>")] + frame * 1_000_000 + b"</data></root>\n")
    code = ("import json, sys\nfrom firmware_io.recordings.importers import import_any\n"
            "from firmware_io.recordings.recording import RecordingError\n"
            f"before = {PEAK_MB}\ntry:\n    import_any(sys.argv[1]); said = ''\n"
            "except RecordingError as exc:\n    said = str(exc)\n"
            f"print(json.dumps({{'said': said, 'mb': {PEAK_MB} - before}}))")
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, cwd=root,
                          env=dict(os.environ, PYTHONPATH=str(root)), timeout=60, check=True)
    got = json.loads(done.stdout)
    assert got["said"].startswith(f"{path}: declares 1000000 frames of 486 taxels"), got
    assert got["mb"] < path.stat().st_size / 2**20 + 40, got


def test_more_frames_than_a_recording_holds_are_refused_whatever_the_taxels(tmp_path, monkeypatch):
    """A layout of few taxels keeps the values small while millions of frames fill the memory: frames have
    their own bound (``MAX_FRAMES``, lowered here to keep the file small)."""
    from firmware_io.recordings.importers import _common

    monkeypatch.setattr(_common, "MAX_FRAMES", 30)
    path = write_dsa(tmp_path / "long.dsa", synthetic_frames(40), 1_400_000_000_000 + np.arange(40) * 31)
    with pytest.raises(RecordingError, match=r"declares 40 frames; refused \(at most 30"):
        read_dsa(path)
