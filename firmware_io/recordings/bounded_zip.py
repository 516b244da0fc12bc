"""Reading ZIP members (JSON and ``.npy``) with limits: sizes, shapes, nesting depth.

Why: a recording is a file from elsewhere, and a deflate bomb, a huge declared ``.npy`` shape or deeply
nested JSON would exhaust memory or the stack. Every refusal is a one-line ``LimitError``.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Sequence

import numpy as np

from firmware_io.errors import HandoverError

__all__ = ["LimitError", "first_line", "loads", "quote", "read_json", "read_npy"]

CHUNK = 1 << 20


class LimitError(HandoverError, ValueError):
    """A member over its size, shape or nesting limit, or not what it says it is."""


def _info(zf: zipfile.ZipFile, name: str, cap: int) -> zipfile.ZipInfo:
    info = zf.getinfo(name)
    if info.compress_type != zipfile.ZIP_STORED:
        raise LimitError(f"member {name} is compressed; handover reads only the uncompressed files it writes "
                         "(save it again with handover, or unzip and zip it with -0)")
    if info.file_size > cap:
        raise LimitError(f"member {name} declares {info.file_size} bytes, over the limit of {cap}")
    return info


def read_member(zf: zipfile.ZipFile, name: str, cap: int) -> bytes:
    """All bytes of a member, never more than ``cap`` (checked while inflating, not only declared)."""
    info = _info(zf, name, cap)
    out = bytearray()
    with zf.open(info) as fh:
        while chunk := fh.read(min(CHUNK, cap + 1 - len(out))):
            out += chunk
            if len(out) > cap:
                raise LimitError(f"member {name} inflates to more than {cap} bytes")
    return bytes(out)


def read_json(zf: zipfile.ZipFile, name: str, cap: int) -> object:
    """A JSON member of at most ``cap`` bytes, nested no deeper than the JSON parser's recursion limit."""
    data = read_member(zf, name, cap)  # its LimitError (compressed, too large) is not a JSON problem
    try:
        return loads(data)
    except ValueError as exc:
        raise LimitError(f"member {name} is not valid JSON ({first_line(exc)})") from None


def loads(text: str | bytes) -> object:
    """``json.loads`` where nesting deeper than the parser's recursion limit (100,000 brackets) is a
    ValueError like any other malformed JSON, not a RecursionError that escapes as a traceback."""
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError("nested deeper than any JSON handover writes") from None


def read_npy(zf: zipfile.ZipFile, name: str, dtype: np.dtype | str, shape: Sequence[int]) -> np.ndarray:
    """An ``.npy`` member that must hold exactly ``dtype`` and ``shape`` (C order): its header is
    checked before any data is read, and the data is read into one preallocated array."""
    want_dtype, want_shape = np.dtype(dtype), tuple(int(n) for n in shape)
    nbytes = int(np.prod(want_shape, dtype=np.int64)) * want_dtype.itemsize
    info = _info(zf, name, nbytes + 65536 + 128)
    with zf.open(info) as fh:
        try:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                got_shape, fortran, got_dtype = np.lib.format.read_array_header_1_0(fh)
            elif version in ((2, 0), (3, 0)):
                got_shape, fortran, got_dtype = np.lib.format.read_array_header_2_0(fh)
            else:
                raise LimitError(f"member {name}: .npy format version {version} is not supported")
        except (ValueError, SyntaxError, EOFError, OSError) as exc:
            raise LimitError(f"member {name} is not an .npy array ({first_line(exc)})") from None
        if got_dtype != want_dtype or tuple(got_shape) != want_shape or fortran:
            raise LimitError(f"member {name} holds {got_dtype} {list(got_shape)}{' (Fortran order)' if fortran else ''}, "
                             f"expected {want_dtype} {list(want_shape)}")
        out = np.empty(want_shape, dtype=want_dtype)
        view = memoryview(out.reshape(-1).view(np.uint8))
        done = 0
        while done < nbytes:
            n = fh.readinto(view[done : done + CHUNK])
            if not n:
                raise LimitError(f"member {name} ends after {done} of {nbytes} data bytes")
            done += n
        if fh.read(1):
            raise LimitError(f"member {name} has data beyond its {list(want_shape)} array")
    return out


def first_line(exc: BaseException) -> str:
    """What a refusal quotes of an exception: its first line, at most 200 characters."""
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else type(exc).__name__


def quote(value: object) -> str:
    """What a refusal quotes of a value from a file: its repr, never more than a line's worth."""
    text = repr(value)
    return text if len(text) <= 40 else text[:36] + "..."
