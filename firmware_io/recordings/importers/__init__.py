"""Importers for recordings users already have: DSA-Konqueror ``.dsa`` files and ROS bags.

``import_any(path)`` chooses by suffix or folder content; each importer returns a
``Recording`` (no trials: the real files carry no handover labels) or raises one
``RecordingError`` naming the file. ``rosbags`` is imported only when a bag is read.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

from firmware_io.recordings.importers.dsa import read_dsa
from firmware_io.recordings.recording import SUFFIX as HREC_SUFFIX
from firmware_io.recordings.recording import Recording, RecordingError

__all__ = ["find_sources", "import_any", "read_dsa", "read_rosbag"]

KNOWN_FORMATS = ".dsa (DSA-Konqueror), .bag (ROS 1), ROS 2 bag folder (metadata.yaml), .hrec"


def read_rosbag(path: str | os.PathLike, topic: str | None = None) -> Recording:
    """See ``firmware_io.recordings.importers.rosbag.read_rosbag`` (imported here lazily)."""
    from firmware_io.recordings.importers.rosbag import read_rosbag as _read

    return _read(path, topic)


def _ros2_folder(path: Path) -> Path | None:
    """The ROS 2 bag folder a path names (the folder itself or a .db3/.mcap inside it)."""
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return path
    if path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
        return path.parent
    return None


def import_any(path: str | os.PathLike, topic: str | None = None) -> Recording:
    """Read any supported recording; unknown formats raise RecordingError naming the file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".dsa":
        return read_dsa(path)
    if suffix == ".bag":
        return read_rosbag(path, topic)
    folder = _ros2_folder(path)
    if folder is not None:
        return read_rosbag(folder, topic)
    if suffix == HREC_SUFFIX:
        return Recording.load(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such file or folder")
    if suffix in (".db3", ".mcap"):
        raise RecordingError(f"{path}: a ROS 2 bag file needs its folder with metadata.yaml beside it")
    raise RecordingError(f"{path}: unknown recording format (known: {KNOWN_FORMATS})")


def find_sources(folder: str | os.PathLike) -> Iterator[Path]:
    """Every importable source below a folder, sorted: .dsa, .bag files and ROS 2 bag folders."""
    folder = Path(folder)
    for p in sorted(folder.rglob("*")):
        if (p.is_file() and p.suffix.lower() in (".dsa", ".bag")) or (p.is_dir() and (p / "metadata.yaml").is_file()):
            yield p
