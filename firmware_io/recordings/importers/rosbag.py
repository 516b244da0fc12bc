"""ROS 1 / ROS 2 bags of ``schunk_sdh/TactileSensor`` -> Recording (via ``rosbags``, no ROS needed).

ROS 2 bags may lack the message definition, so it is registered here. Matrices go in ``matrix_id``
(wire) order; what the messages lack of the layout comes from the SDH-2 default. Time stamps come from
the headers, else the receive time (``meta["time_source"]``); as in the DSA importer, frames whose time
does not advance are dropped and counted, and values must be raw 12-bit counts.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from firmware_io.layout import FULL_SCALE_12BIT, LayoutError, MatrixInfo, SensorLayout
from firmware_io.recordings.importers._common import check_range, describe_timing, keep_increasing
from firmware_io.recordings.recording import Recording, RecordingError

__all__ = ["MATRIX_MSGTYPE", "MSGTYPE", "read_rosbag", "typestore"]

MSGTYPE = "schunk_sdh/msg/TactileSensor"
MATRIX_MSGTYPE = "schunk_sdh/msg/TactileMatrix"

TACTILE_SENSOR_MSG = """\
std_msgs/Header header
schunk_sdh/TactileMatrix[] tactile_matrix
"""

TACTILE_MATRIX_MSG = """\
uint32 matrix_id
int16 cells_x
int16 cells_y
int16[] tactile_array
"""

_DISTAL_MASK = SensorLayout.sdh2().matrices[1].static_mask

_INSTALL_HINT = "reading ROS bags needs the 'rosbags' package: pip install 'tactile-handover[train]'"


def is_ros2_bag(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def typestore():
    """A ROS 2 type store with the schunk_sdh messages registered (also used to write test bags)."""
    try:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ModuleNotFoundError:
        raise RecordingError(_INSTALL_HINT) from None
    store = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    types.update(get_types_from_msg(TACTILE_MATRIX_MSG, MATRIX_MSGTYPE))
    types.update(get_types_from_msg(TACTILE_SENSOR_MSG, MSGTYPE))
    store.register(types)
    return store


def read_rosbag(path: str | os.PathLike, topic: str | None = None) -> Recording:
    """Read the tactile topic of one bag; any problem raises one RecordingError naming the bag."""
    path = Path(path)
    try:
        return _read(path, topic)
    except RecordingError as exc:
        msg = str(exc)
        raise RecordingError(msg if msg.startswith(str(path)) or msg == _INSTALL_HINT else f"{path}: {msg}") from None


def _read(path: Path, topic: str | None) -> Recording:
    if not path.exists():
        raise RecordingError("no such file or folder")
    if path.is_dir() and not is_ros2_bag(path):
        raise RecordingError("folder is not a ROS 2 bag (no metadata.yaml)")
    store = typestore()
    try:
        from rosbags.highlevel import AnyReader, AnyReaderError
    except ModuleNotFoundError:
        raise RecordingError(_INSTALL_HINT) from None
    try:
        with AnyReader([path], default_typestore=store) as reader:
            connections = _tactile_connections(reader.connections, topic)
            stamps, bag_times, matrices = [], [], []
            for conn, bag_time, raw in reader.messages(connections=connections):
                msg = reader.deserialize(raw, conn.msgtype)
                stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
                bag_times.append(bag_time)
                matrices.append(sorted(msg.tactile_matrix, key=lambda m: m.matrix_id))
            chosen = connections[0].topic
    except RecordingError:
        raise
    except AnyReaderError as exc:
        raise RecordingError(f"not a readable ROS bag ({exc})") from None
    except Exception as exc:  # rosbags raises many kinds of errors on damaged input
        raise RecordingError(f"damaged ROS bag ({type(exc).__name__}: {exc})") from None
    if not matrices:
        raise RecordingError(f"topic {chosen} holds no messages")
    layout = _layout(matrices[0])
    frames = _frames(matrices, layout)
    header_ns = np.array(stamps, dtype=np.int64)
    use_header = bool(np.any(header_ns != 0))
    ns = header_ns if use_header else np.array(bag_times, dtype=np.int64)
    times = (ns - ns[0]).astype(np.float64) / 1e9
    frames, times, dropped = keep_increasing(frames, times)
    meta = {
        "source": path.name,
        "source_format": "ros2-bag" if path.is_dir() else "ros1-bag",
        "topic": chosen,
        "time_source": "header" if use_header else "bag",
        "time_origin_unix": float(ns[0]) / 1e9,
        **dropped,
        **describe_timing(times),
    }
    return Recording(layout, frames, times, [], meta)


def _tactile_connections(connections, topic: str | None) -> list:
    found = sorted({c.topic for c in connections})
    if topic is not None:
        chosen = [c for c in connections if c.topic == topic]
        if not chosen:
            raise RecordingError(f"no topic {topic!r} (topics: {', '.join(found) or 'none'})")
        if not chosen[0].msgtype.endswith("TactileSensor"):
            raise RecordingError(f"topic {topic!r} carries {chosen[0].msgtype}, not schunk_sdh/TactileSensor")
        return chosen
    tactile = [c for c in connections if c.msgtype.replace("/msg/", "/") == "schunk_sdh/TactileSensor"]
    topics = sorted({c.topic for c in tactile})
    if not topics:
        raise RecordingError(f"no schunk_sdh/TactileSensor topic (topics: {', '.join(found) or 'none'})")
    if len(topics) > 1:
        raise RecordingError(f"several TactileSensor topics ({', '.join(topics)}): choose one with --topic")
    return tactile


def _layout(first: list) -> SensorLayout:
    ids = [int(m.matrix_id) for m in first]
    if ids != list(range(len(ids))):
        raise RecordingError(f"matrix ids {ids} are not 0..{len(ids) - 1}")
    default = SensorLayout.sdh2()
    mats = []
    for m in first:
        i, cx, cy = int(m.matrix_id), int(m.cells_x), int(m.cells_y)
        ref = default.matrices[i] if i < default.n_matrices else None
        same = ref is not None and (ref.cells_x, ref.cells_y) == (cx, cy)
        try:
            mats.append(
                MatrixInfo(
                    index=i,
                    cells_x=cx,
                    cells_y=cy,
                    center=ref.center if same else (0.0, 0.0, 0.0),
                    fullscale=float(FULL_SCALE_12BIT),
                    static_mask=_DISTAL_MASK if (cx, cy) == (6, 13) else None,
                )
            )
        except LayoutError as exc:
            raise RecordingError(f"bad matrix in first message: {exc}") from None
    return SensorLayout(tuple(mats))


def _frames(messages: list[list], layout: SensorLayout) -> np.ndarray:
    sizes = [(m.cells_x, m.cells_y) for m in layout.matrices]
    for k, mats in enumerate(messages):  # every size checked before the frames are allocated: a message may
        if [(int(m.cells_x), int(m.cells_y)) for m in mats] != sizes:  # declare any size, only its array is real
            raise RecordingError(f"message {k}: matrix sizes differ from the first message")
        if any(len(m.tactile_array) != m.cells_x * m.cells_y for m in mats):
            raise RecordingError(f"message {k}: a tactile_array length does not match cells_x * cells_y")
    out = np.empty((len(messages), layout.n_taxels), dtype=np.int32)
    for k, mats in enumerate(messages):
        out[k] = np.concatenate([np.asarray(m.tactile_array) for m in mats])
    check_range(out, layout.fullscale, "message")
    return out.astype(np.uint16)
