"""A minimal reader of the ONNX protobuf wire format: operator domains and external data.

Why not the ``onnx`` package: the daemon installs numpy + onnxruntime only, and onnxruntime
does not expose the graph's operator domains. Reading the few fields needed straight from the
protobuf wire format (varints and length-delimited fields; see onnx/onnx.proto) is short,
has no dependency and no version skew, and is checked against ``onnx`` in the tests.

Fields used (onnx.proto3 numbers, onnx 1.23): ModelProto.graph = 7, .opset_import = 8,
.functions = 25; GraphProto.node = 1, .initializer = 5, .sparse_initializer = 15;
NodeProto.attribute = 5, .domain = 7; AttributeProto.t = 5, .g = 6, .tensors = 10,
.graphs = 11, .sparse_tensor = 22, .sparse_tensors = 23; SparseTensorProto.values = 1,
.indices = 2; TensorProto.dims = 1, .data_type = 2, .float_data = 4, .name = 8, .raw_data = 9,
.double_data = 10, .external_data = 13, .data_location = 14, .int32_data = 5 (float16 bits);
NodeProto.output = 2, .op_type = 4; AttributeProto.f = 2, .floats = 7;
OperatorSetIdProto.domain = 1; FunctionProto.input = 4 (strings, skipped), .node = 7,
.opset_import = 9, .domain = 10.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

from firmware_io.errors import HandoverError

__all__ = ["WireError", "summarize"]


class WireError(HandoverError, ValueError):
    """Bytes that are not a well-formed protobuf message."""


@dataclass
class WireSummary:
    """What the contract checks that onnxruntime's Python API does not tell."""

    opset_domains: set[str] = field(default_factory=set)
    node_domains: set[str] = field(default_factory=set)
    n_nodes: int = 0
    external_data: bool = False
    initializer_dims: dict[str, tuple[int, ...]] = field(default_factory=dict)
    """Shape of every initializer of the main graph, by name (what the contract checks K and W on)."""
    nan_initializers: list[str] = field(default_factory=list)
    """Float constants (initializers, sparse ones and Constant nodes, in any graph, subgraphs and
    functions included; float, double, float16, bfloat16) holding a NaN: never a deliberate value
    (infinities can be: the padded median's offsets are +-inf), so a damaged or badly fitted model."""


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        if pos >= len(buf):
            raise WireError("truncated varint")
        byte = buf[pos]
        pos += 1
        result |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise WireError("varint too long")


def _fields(buf: bytes) -> Iterator[tuple[int, int, bytes | int]]:
    """Yield (field number, wire type, value) of one message; length-delimited values as bytes."""
    pos, end = 0, len(buf)
    while pos < end:
        key, pos = _varint(buf, pos)
        number, wtype = key >> 3, key & 7
        if wtype == 0:
            value, pos = _varint(buf, pos)
        elif wtype == 1:
            value, pos = buf[pos : pos + 8], pos + 8
        elif wtype == 2:
            length, pos = _varint(buf, pos)
            if pos + length > end:
                raise WireError(f"field {number} runs past the end of its message")
            value, pos = buf[pos : pos + length], pos + length
        elif wtype == 5:
            value, pos = buf[pos : pos + 4], pos + 4
        else:
            raise WireError(f"unsupported wire type {wtype} (field {number})")
        if pos > end:
            raise WireError("truncated message")
        yield number, wtype, value


def _nested(buf: bytes) -> Iterator[tuple[int, bytes]]:
    """(field number, bytes) of one message's length-delimited fields: the strings, nested messages
    and packed arrays the walks below look into (varint and fixed-size fields are passed over)."""
    return ((number, value) for number, wtype, value in _fields(buf) if wtype == 2)


def _first_string(buf: bytes, number: int) -> str:
    """The first string in field ``number`` ("" without one): a ValueInfoProto's name, an opset's domain (1)."""
    return next((v.decode("utf-8", "replace") for n, v in _nested(buf) if n == number), "")


def _tensor_is_external(buf: bytes) -> bool:
    return any(number == 13 or (number == 14 and value == 1) for number, _, value in _fields(buf))


def _sparse_is_external(buf: bytes) -> bool:
    """A SparseTensorProto whose values (1) or indices (2) tensor lives in external data."""
    return any(number in (1, 2) and _tensor_is_external(v) for number, v in _nested(buf))


_FLOAT_TYPES = {1: "<f4", 11: "<f8", 14: "<f4", 15: "<f8"}
"""TensorProto.data_type (2) -> numpy dtype of its raw_data (9) / packed float_data (4) or double_data (10)
(complex64 / complex128: real and imaginary parts in turn, each a float / double)."""
_FLOAT8_NANS = {17: frozenset((0x7F, 0xFF)), 18: frozenset((0x80,)),
                19: frozenset(b for b in range(256) if b & 0x7C == 0x7C and b & 0x03), 20: frozenset((0x80,))}
"""float8 e4m3fn / e4m3fnuz / e5m2 / e5m2fnuz (data_type 17-20): the byte values that are NaN; values sit in
raw_data (9), a byte each, or in int32_data (5), one varint each."""
_HALF_NAN = {10: (0x7C00, 0x03FF), 16: (0x7F80, 0x007F)}
"""float16 / bfloat16 (data_type 10 / 16): (exponent mask, mantissa mask) of a NaN's bits; their
values sit in raw_data (9) as little-endian uint16 or in int32_data (5), one varint each."""


def _varints(value: bytes | int) -> list[int]:
    if isinstance(value, int):
        return [value]
    out, pos = [], 0
    while pos < len(value):
        number, pos = _varint(value, pos)
        out.append(number)
    return out


def _has_nan(buf: bytes) -> bool:
    """Whether a float, double, complex, float16, bfloat16 or float8 TensorProto's values hold a NaN."""
    import numpy as np

    data_type, chunks, halves = 0, [], []
    for number, wtype, value in _fields(buf):
        if number == 2 and wtype == 0:
            data_type = value
        elif (wtype == 2 and number in (4, 9, 10)) or (wtype, number) in ((5, 4), (1, 10)):  # packed or one value
            chunks.append(value)
        elif number == 5 and wtype in (0, 2):
            halves.extend(_varints(value))
    if data_type in _FLOAT8_NANS:
        nans = _FLOAT8_NANS[data_type]
        return any(b in nans for c in chunks for b in c) or any(v in nans for v in halves)
    if data_type in _HALF_NAN:
        exponent, mantissa = _HALF_NAN[data_type]
        bits = [b for c in chunks if len(c) % 2 == 0 for b in np.frombuffer(c, dtype="<u2").tolist()] + halves
        return any(b & exponent == exponent and b & mantissa for b in bits)
    dtype = _FLOAT_TYPES.get(data_type)
    return dtype is not None and _any_nan(chunks, dtype)


def _any_nan(chunks: list[bytes], dtype: str) -> bool:
    """Whether little-endian ``dtype`` values packed in ``chunks`` hold a NaN (a chunk of the wrong
    length for the type is skipped: the loader refuses a damaged tensor by other means)."""
    import numpy as np

    size = np.dtype(dtype).itemsize
    return any(len(c) % size == 0 and np.isnan(np.frombuffer(c, dtype=dtype)).any() for c in chunks)


def _constant_has_nan(attribute: bytes) -> bool:
    """A Constant node's attribute holding NaN: its value tensor (5) or value_float(s) (2, 7).
    Only Constant nodes: other operators may mean NaN (TreeEnsemble's set separators, Imputer)."""
    floats = []
    for number, wtype, value in _fields(attribute):
        if number == 5 and wtype == 2:
            return _has_nan(value)
        if number == 22 and wtype == 2:
            return _sparse_has_nan(value)
        if (number, wtype) in ((2, 5), (7, 5), (7, 2)):
            floats.append(value)
    return _any_nan(floats, "<f4")


def _sparse_has_nan(buf: bytes) -> bool:
    """A SparseTensorProto whose values tensor (1) holds NaN."""
    return any(number == 1 and _has_nan(value) for number, value in _nested(buf))


def _tensor_name_and_dims(buf: bytes) -> tuple[str, tuple[int, ...]]:
    name, dims = "", []
    for number, wtype, value in _fields(buf):
        if number == 8 and wtype == 2:
            name = value.decode("utf-8", "replace")
        elif number == 1 and wtype == 0:
            dims.append(value)
        elif number == 1 and wtype == 2:  # packed
            pos = 0
            while pos < len(value):
                dim, pos = _varint(value, pos)
                dims.append(dim)
    return name, tuple(dims)


def _walk_graph(buf: bytes, out: WireSummary, main: bool = False) -> None:
    for number, value in _nested(buf):
        if number == 1:
            _walk_node(value, out)
        elif number == 5:
            if _tensor_is_external(value):
                out.external_data = True
            name, dims = _tensor_name_and_dims(value)
            if main:
                out.initializer_dims[name] = dims
            if _has_nan(value):
                out.nan_initializers.append(name)
        elif number == 15:
            if _sparse_is_external(value):
                out.external_data = True
            if _sparse_has_nan(value):
                out.nan_initializers.append(_sparse_name(value))


def _sparse_name(buf: bytes) -> str:
    return next((_tensor_name_and_dims(v)[0] for n, v in _nested(buf) if n == 1), "")


def _walk_node(buf: bytes, out: WireSummary) -> None:
    out.n_nodes += 1
    domain, op_type, outputs, attributes = "", "", [], []
    for number, value in _nested(buf):
        if number == 7:
            domain = value.decode("utf-8", "replace")
        elif number == 4:
            op_type = value.decode("utf-8", "replace")
        elif number == 2:
            outputs.append(value.decode("utf-8", "replace"))
        elif number == 5:
            attributes.append(value)
            for a_number, a_value in _nested(value):
                if a_number in (6, 11):
                    _walk_graph(a_value, out)
                elif (a_number in (5, 10) and _tensor_is_external(a_value)) or (
                    a_number in (22, 23) and _sparse_is_external(a_value)
                ):
                    out.external_data = True
    out.node_domains.add(domain)
    if op_type == "Constant" and domain in ("", "ai.onnx") and any(_constant_has_nan(a) for a in attributes):
        out.nan_initializers.append(outputs[0] if outputs else "Constant")


def summarize(model_bytes: bytes) -> WireSummary:
    """Operator domains (opset imports and every node, subgraphs and functions included) and
    whether any tensor lives in external data. Raises WireError on malformed bytes."""
    out = WireSummary()
    saw_graph = False
    for number, value in _nested(model_bytes):
        if number == 7:
            saw_graph = True
            _walk_graph(value, out, main=True)
        elif number == 8:
            out.opset_domains.add(_first_string(value, 1))
        elif number == 25:
            for f_number, f_value in _nested(value):
                if f_number == 7:
                    _walk_node(f_value, out)
                elif f_number == 9:
                    out.opset_domains.add(_first_string(f_value, 1))
                elif f_number == 10:
                    out.node_domains.add(f_value.decode("utf-8", "replace"))
    if not saw_graph:
        raise WireError("no graph in the model")
    return out


# -- one graph's part: the nodes some outputs need -------------------------------------------------
def _encode_varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _encode_field(number: int, wtype: int, value: bytes | int) -> bytes:
    key = _encode_varint((number << 3) | wtype)
    if wtype == 0:
        return key + _encode_varint(int(value))
    if wtype == 2:
        return key + _encode_varint(len(value)) + bytes(value)
    return key + bytes(value)  # fixed 32/64-bit: already the raw bytes


def _strings(buf: bytes, number: int) -> list[str]:
    return [v.decode("utf-8", "replace") for n, v in _nested(buf) if n == number]


def keep_outputs(model_bytes: bytes, outputs: tuple[str, ...]) -> bytes:
    """The model with only the nodes, initializers and graph outputs that ``outputs`` need (the same
    bytes for everything kept). Why: onnxruntime runs every node of a graph whatever outputs are
    asked for, so a file with several heads is opened as one session per head. Raises WireError
    when an output is not in the graph."""
    graph = next((v for n, v in _nested(model_bytes) if n == 7), None)
    if graph is None:
        raise WireError("no graph in the model")
    items = list(_fields(graph))
    names = {_first_string(v, 1) for n, t, v in items if n == 12 and t == 2}
    missing = [o for o in outputs if o not in names]
    if missing:
        raise WireError(f"the graph has no output {missing[0]!r}")
    needed = set(outputs)
    keep_node: dict[int, bool] = {}
    for i in range(len(items) - 1, -1, -1):  # nodes are stored in topological order
        number, wtype, value = items[i]
        if number == 1 and wtype == 2 and needed.intersection(_strings(value, 2)):
            keep_node[i] = True
            needed.update(_strings(value, 1))
    body = bytearray()
    for i, (number, wtype, value) in enumerate(items):
        if number == 1 and wtype == 2 and not keep_node.get(i):
            continue
        if number == 5 and wtype == 2 and _tensor_name_and_dims(value)[0] not in needed:
            continue
        if number == 12 and wtype == 2 and _first_string(value, 1) not in outputs:
            continue
        if number == 13:  # intermediate shapes: onnxruntime infers them again
            continue
        body += _encode_field(number, wtype, value)
    out = bytearray()
    for number, wtype, value in _fields(model_bytes):
        out += _encode_field(7, 2, bytes(body)) if number == 7 and wtype == 2 else _encode_field(number, wtype, value)
    return bytes(out)
