"""DSA-Konqueror ``.dsa`` files -> Recording.

A ``.dsa`` file is bzip2-compressed (or plain) XML: a ``<sensor>`` header, then ``<frame>`` elements with
a PC ``<time_stamp>`` in ms and hex ``<frame_data>`` (big-endian float32 tokens; -n stands for n zeros).
Why regular expressions for the frames: a folder of ~20 000-frame files must import in seconds. What
the pattern does not account for is an error, never skipped; values must be raw 12-bit counts (nothing
is clipped), and frames whose time stamp does not advance are dropped and counted in meta.
"""

from __future__ import annotations

import bz2
import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from firmware_io.layout import FULL_SCALE_12BIT, LayoutError, MatrixInfo, SensorLayout
from firmware_io.recordings.importers._common import (
    check_allocation,
    check_fullscale,
    check_range,
    describe_timing,
    keep_increasing,
)
from firmware_io.recordings.recording import Recording, RecordingError

__all__ = ["MAX_XML_BYTES", "SUFFIX", "read_dsa"]

SUFFIX = ".dsa"

_FRAME_RE = re.compile(
    rb"<frame\b[^>]*>\s*<time_stamp>\s*(\d+)\s*</time_stamp>\s*<frame_data>([^<]*)</frame_data>\s*</frame>"
)
_FRAME_COUNT_RE = re.compile(rb"<frame_count>\s*(\d+)\s*</frame_count>")
_WHITESPACE = b" \t\r\n"


def read_dsa(path: str | os.PathLike) -> Recording:
    """Read one DSA-Konqueror file; any problem raises one RecordingError naming the file."""
    path = Path(path)
    try:
        return _read(path)
    except RecordingError as exc:
        msg = str(exc)
        raise RecordingError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None


def _read(path: Path) -> Recording:
    text = _decompress(path)
    data_start = text.find(b"<data>")
    if data_start < 0:
        raise RecordingError("not a DSA-Konqueror recording (no <data> section)")
    layout, header_meta = _parse_header(bytes(text[:data_start]))
    if text.find(b"</data>", data_start) < 0:
        raise RecordingError("truncated: the <data> section has no end tag")
    stamps_ms, frames = _parse_frames(text, data_start, layout)
    stamps = (stamps_ms - stamps_ms[0]).astype(np.float64) / 1000.0
    frames, stamps, dropped = keep_increasing(frames, stamps)
    meta = {
        "source": path.name,
        "source_format": "dsa-konqueror",
        "time_origin_unix": float(stamps_ms[0]) / 1000.0,
        **header_meta,
        **dropped,
        **describe_timing(stamps),
    }
    return Recording(layout, frames, stamps, [], meta)


def _decompress(path: Path) -> bytes | bytearray:
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise RecordingError("no such file") from None
    except IsADirectoryError:
        raise RecordingError("is a folder, not a .dsa file") from None
    except OSError as exc:
        raise RecordingError(f"cannot read ({exc.strerror or exc})") from None
    if raw.startswith(b"BZh"):
        try:
            return _bunzip(raw, MAX_XML_BYTES)
        except EOFError:
            raise RecordingError("truncated (the bzip2 stream ends early)") from None
        except (OSError, ValueError) as exc:
            raise RecordingError(f"corrupt bzip2 data ({exc})") from None
    if raw.lstrip().startswith((b"<?xml", b"<root")):
        return raw
    raise RecordingError("not a DSA-Konqueror recording (neither bzip2 nor XML)")


MAX_XML_BYTES = 256 << 20
"""A DSA-Konqueror file of 20,000 frames without a single zero run is about 90 MB of XML (the
real files of ../shared/data inflate to a few MB)."""


def _bunzip(raw: bytes, cap: int) -> bytearray:
    """bzip2 (one or more concatenated streams) inflated to at most ``cap`` bytes: a bomb is
    refused while inflating, not after it filled the memory."""
    out = bytearray()
    while raw:
        d = bz2.BZ2Decompressor()
        out += d.decompress(raw, max_length=cap + 1 - len(out))
        while not d.eof and not d.needs_input and len(out) <= cap:
            out += d.decompress(b"", max_length=cap + 1 - len(out))
        if len(out) > cap:
            raise RecordingError(f"inflates to more than {cap >> 20} MiB of XML; refused (a bzip2 bomb?)")
        if not d.eof:
            raise EOFError
        raw = d.unused_data
    return out


def _parse_header(head: bytes) -> tuple[SensorLayout, dict]:
    try:
        root = ET.fromstring(head + b"</root>")
    except ET.ParseError as exc:
        raise RecordingError(f"broken XML header ({exc})") from None
    sensor = root.find("sensor")
    if sensor is None:
        raise RecordingError("not a DSA-Konqueror recording (no <sensor> header)")
    matrices = [_parse_matrix(m) for m in sensor.findall("matrix")]
    if not matrices:
        raise RecordingError("the <sensor> header describes no matrix")
    declared = _int_or_none(sensor.findtext("num_matrices"))
    if declared is not None and declared != len(matrices):
        raise RecordingError(f"header says {declared} matrices but describes {len(matrices)}")
    try:
        layout = SensorLayout.from_matrix_infos(matrices)
    except LayoutError as exc:
        raise RecordingError(f"bad sensor header: {exc}") from None
    meta: dict = {}
    for key in ("serial_nr", "generated_by", "hw_revision", "converter_resolution"):
        value = sensor.findtext(key)
        if value is not None and value.strip():
            meta[f"dsa_{key}"] = value.strip()
    dynamic = {}
    for m in sensor.findall("matrix"):
        mask = _mask_rows(m.findtext("dynamic_mask"))
        if mask is not None and not all(set(row) == {"1"} for row in mask):
            dynamic[m.get("index", "?")] = mask
    if dynamic:
        meta["dsa_dynamic_masks"] = dynamic
    return layout, meta


def _parse_matrix(m: ET.Element) -> MatrixInfo:
    try:
        index = int(m.get("index", ""))
        cells_x, cells_y = int(m.findtext("cells_x", "")), int(m.findtext("cells_y", ""))
        width = float(m.findtext("texel_width") or 3.4)
        height = float(m.findtext("texel_height") or 3.4)
        center = tuple(float(m.findtext(f"matrix_center_{a}") or 0.0) for a in "xyz")
        fullscale = float(m.findtext("fullscale") or FULL_SCALE_12BIT)
    except ValueError as exc:
        raise RecordingError(f"bad <matrix> header ({exc})") from None
    check_fullscale(fullscale, f"matrix {index}")
    if not all(np.isfinite((width, height, *center))):
        raise RecordingError(f"matrix {index}: texel size and centre must be finite numbers")
    rows = _mask_rows(m.findtext("static_mask"))
    mask = None
    if rows is not None:
        if len(rows) != cells_y or any(len(r) != cells_x or set(r) - {"0", "1"} for r in rows):
            raise RecordingError(f"matrix {index}: static mask is not {cells_y} rows of {cells_x} 0/1 digits")
        mask = np.array([[c == "1" for c in r] for r in rows], dtype=bool)
        if mask.all():
            mask = None
    try:
        return MatrixInfo(index, cells_x, cells_y, width, height, center, fullscale, mask)  # type: ignore[arg-type]
    except LayoutError as exc:
        raise RecordingError(str(exc)) from None


def _mask_rows(text: str | None) -> list[str] | None:
    rows = (text or "").split()
    return rows or None


def _int_or_none(text: str | None) -> int | None:
    try:
        return int(text) if text is not None else None
    except ValueError:
        return None


def _parse_frames(text: bytes | bytearray, start: int, layout: SensorLayout) -> tuple[np.ndarray, np.ndarray]:
    """Time stamps (int64 ms) and frames (uint16 [N, C]) from the <data> section at ``start``. The frame
    tags are counted in place and the size checked before any frame is cut out: the list of millions of
    cut-out frames was the memory a frame bomb took."""
    n_open = text.count(b"<frame", start) - text.count(b"<frame_", start)
    check_allocation(n_open, layout.n_taxels, len(text) - start)
    matches = _FRAME_RE.findall(text, start)
    if n_open != len(matches):
        raise RecordingError(f"{n_open - len(matches)} of {n_open} <frame> elements are malformed")
    declared = _FRAME_COUNT_RE.search(text, start)
    if declared is not None and int(declared.group(1)) != len(matches):
        raise RecordingError(f"header says {int(declared.group(1))} frames, the file holds {len(matches)}")
    if not matches:
        raise RecordingError("holds no frames")
    try:
        stamps_ms = np.array([int(t) for t, _ in matches], dtype=np.int64)
    except OverflowError:
        raise RecordingError("a <time_stamp> does not fit in 64 bits (ms since 1970 do)") from None
    hex_parts = [d.translate(None, _WHITESPACE) for _, d in matches]
    n_hex = np.array([len(h) for h in hex_parts], dtype=np.int64)
    odd = np.flatnonzero((n_hex % 8 != 0) | (n_hex == 0))
    if odd.size:
        raise RecordingError(f"frame {odd[0]}: frame_data has {n_hex[odd[0]]} hex digits, not a positive multiple of 8")
    try:
        tokens = np.frombuffer(bytes.fromhex(b"".join(hex_parts).decode("ascii")), dtype=">f4").astype(np.float64)
    except (ValueError, UnicodeDecodeError):
        raise RecordingError("frame_data holds characters that are not hex digits") from None
    return stamps_ms, _expand(tokens, n_hex // 8, layout)


def _expand(tokens: np.ndarray, per_frame: np.ndarray, layout: SensorLayout) -> np.ndarray:
    """Expand zero runs (-n -> n zeros) and check each frame has exactly n_taxels values."""
    n_taxels = layout.n_taxels
    starts = np.concatenate(([0], np.cumsum(per_frame)[:-1]))
    frame_of = np.repeat(np.arange(len(per_frame)), per_frame)
    bad = ~np.isfinite(tokens)
    if bad.any():
        raise RecordingError(f"frame {frame_of[np.argmax(bad)]}: NaN or infinite value")
    runs = tokens < 0
    run_len = -tokens
    bad = runs & ((run_len != np.round(run_len)) | (run_len > n_taxels))
    if bad.any():
        i = int(np.argmax(bad))
        raise RecordingError(f"frame {frame_of[i]}: zero run {tokens[i]:g} is not -1..-{n_taxels}")
    lengths = np.where(runs, run_len, 1.0).astype(np.int64)
    sizes = np.add.reduceat(lengths, starts)
    wrong = np.flatnonzero(sizes != n_taxels)
    if wrong.size:
        f = int(wrong[0])
        raise RecordingError(
            f"frame {f} has {sizes[f]} taxels, the header describes {n_taxels} ({wrong.size} such frames)"
        )
    values = np.repeat(np.where(runs, 0.0, tokens), lengths).reshape(len(per_frame), n_taxels)
    fractional = values != np.round(values)
    if fractional.any():
        f, c = np.argwhere(fractional)[0]
        raise RecordingError(f"frame {f}, taxel {c}: value {values[f, c]:g} is not a whole ADC count")
    check_range(values, layout.fullscale, "frame")
    return values.astype(np.uint16)
