"""Hostile recording files: what a damaged disk or an attacker could hand ``plot``/``train``/``emulate``.

Each builder writes one ``.hrec`` (a ZIP) that breaks exactly one limit of the reader
(firmware_io.recordings.bounded_zip): a deflate bomb, an ``.npy`` header declaring a huge shape, a deeply
nested JSON header, a layout of the wrong type, and a few more. ``write_all`` writes them all.
"""

from __future__ import annotations

import io
import json
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from firmware_io.frame_timing import NOMINAL_PERIOD_S
from firmware_io.layout import SensorLayout
from firmware_io.recordings.recording import _npy_bytes as _npy

N_FRAMES = 20


def _header(**changes) -> dict:
    layout = SensorLayout.sdh2()
    header = {"format": "handover-recording", "version": 1, "n_frames": N_FRAMES, "n_taxels": layout.n_taxels,
              "layout": layout.to_dict(), "trials": [], "meta": {}}
    header.update(changes)
    return header


def _npy_header(dtype: str, shape: tuple[int, ...]) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buf.getvalue()  # magic string included


def _frames() -> np.ndarray:
    return np.zeros((N_FRAMES, SensorLayout.sdh2().n_taxels), dtype=np.uint16)


def _stamps() -> np.ndarray:
    return np.arange(N_FRAMES, dtype=np.float64) * NOMINAL_PERIOD_S


def _write(path: Path, header: bytes | dict, frames: bytes | None = None) -> Path:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as zf:
        zf.writestr("header.json", header if isinstance(header, bytes) else json.dumps(header))
        zf.writestr("frames.npy", _npy(_frames()) if frames is None else frames)
        zf.writestr("timestamps.npy", _npy(_stamps()))
    return path


def deflate_bomb(path: Path, inflated: int = 2 << 30) -> Path:
    """A frames.npy member of ``inflated`` bytes of zeros, deflated to about a thousandth of that."""
    zero = bytes(1 << 20)
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("header.json", json.dumps(_header()))
        info = zipfile.ZipInfo("frames.npy")
        info.compress_type = zipfile.ZIP_DEFLATED
        with zf.open(info, "w", force_zip64=True) as fh:
            fh.write(_npy_header("<u2", (N_FRAMES, SensorLayout.sdh2().n_taxels)))
            for _ in range(inflated >> 20):
                fh.write(zero)
        zf.writestr("timestamps.npy", _npy(_stamps()))
    return path


def dsa_bomb(path: Path, inflated: int = 2 << 30) -> Path:
    """A DSA-Konqueror file: bzip2 streams of 1 MiB of spaces each, ``inflated`` bytes in all, after
    a valid XML prologue (a few kB on disk; ``bz2.decompress`` would fill the memory)."""
    import bz2

    block = bz2.compress(b" " * (1 << 20))
    with path.open("wb") as fh:
        fh.write(bz2.compress(b'<?xml version="1.0"?>\n<root>\n'))
        for _ in range(inflated >> 20):
            fh.write(block)
    return path


def huge_shape(path: Path) -> Path:
    """frames.npy declares 10**13 frames (88 TiB); the header agrees."""
    n = 10**13
    return _write(path, _header(n_frames=n), frames=_npy_header("<u2", (n, 486)))


def huge_shape_npy_only(path: Path) -> Path:
    """The header says 20 frames, frames.npy declares 10**13."""
    return _write(path, _header(), frames=_npy_header("<u2", (10**13, 486)))


def deep_nesting(path: Path, depth: int = 200_000) -> Path:
    text = json.dumps(_header(meta="@@")).replace('"@@"', "[" * depth + "]" * depth)
    return _write(path, text.encode())


def bogus_layout(path: Path) -> Path:
    return _write(path, _header(layout={"matrices": "six pads"}))


def layout_of_numbers(path: Path) -> Path:
    return _write(path, _header(layout={"matrices": [1, 2, 3]}))


def trials_not_objects(path: Path) -> Path:
    return _write(path, _header(trials=["pull", 3]))


def n_frames_not_a_count(path: Path) -> Path:
    return _write(path, _header(n_frames="twenty"))


def header_not_json(path: Path) -> Path:
    return _write(path, b"\xff\xfe{not json")


def pickled_frames(path: Path) -> Path:
    """An object-dtype .npy (would need pickle to load)."""
    return _write(path, _header(), frames=_npy_header("|O", (N_FRAMES, 486)) + b"\x80\x04N.")


BUILDERS: dict[str, Callable[[Path], Path]] = {
    "huge_shape": huge_shape,
    "huge_shape_npy_only": huge_shape_npy_only,
    "deep_nesting": deep_nesting,
    "bogus_layout": bogus_layout,
    "layout_of_numbers": layout_of_numbers,
    "trials_not_objects": trials_not_objects,
    "n_frames_not_a_count": n_frames_not_a_count,
    "header_not_json": header_not_json,
    "pickled_frames": pickled_frames,
}
"""The cheap ones (milliseconds each); the two bombs are separate (their size is a parameter)."""


def write_all(folder: Path, bomb_bytes: int = 64 << 20) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = {name: build(folder / f"{name}.hrec") for name, build in BUILDERS.items()}
    out["deflate_bomb"] = deflate_bomb(folder / "deflate_bomb.hrec", bomb_bytes)
    out["dsa_bzip2_bomb"] = dsa_bomb(folder / "bzip2_bomb.dsa", bomb_bytes)
    return out
