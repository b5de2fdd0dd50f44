"""What an ONNX file says without loading its graph: its metadata (the model card) and the
size of its graph, read from the protobuf wire format (no `onnx` package: the service does
not depend on it).

ModelProto's fields used: 1 `ir_version`, 7 `graph` (skipped by its length, or its nodes
counted), 14 `metadata_props` (StringStringEntryProto: 1 key, 2 value). Nothing else of the
file is interpreted; onnxruntime checks the rest when it loads the graph.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

_IR_VERSION, _GRAPH, _METADATA = 1, 7, 14
_GRAPH_NODE, _GRAPH_INITIALIZER = 1, 5
_VARINT, _FIXED64, _LENGTH, _FIXED32 = 0, 1, 2, 5


class OnnxFileError(ValueError):
    """The bytes are not an ONNX model's protobuf encoding (or are cut short)."""


@dataclass(frozen=True)
class GraphSize:
    """The size of a graph: its nodes, and the bytes of its initializers (the weights)."""

    nodes: int
    initializer_bytes: int


def _varint(read: BinaryIO) -> int | None:
    """The next varint of `read`, None at the end of the data."""
    value, shift = 0, 0
    while True:
        byte = read.read(1)
        if not byte:
            if shift:
                raise OnnxFileError("cut short inside a number")
            return None
        value |= (byte[0] & 0x7F) << shift
        if byte[0] < 0x80:
            return value
        shift += 7
        if shift > 63:
            raise OnnxFileError("a number longer than 10 bytes")


def _fields(read: BinaryIO, end: int) -> Iterator[tuple[int, int, int]]:
    """(field number, wire type, value) of each field until offset `end`: the value itself
    for a varint, else the length of the field's bytes, which start at `read.tell()` and are
    skipped unless the caller reads them before asking for the next field."""
    while read.tell() < end:
        key = _varint(read)
        if key is None:
            return
        number, wire = key >> 3, key & 7
        if number == 0:
            raise OnnxFileError("field number 0")
        if wire == _VARINT:
            value = _varint(read)
            if value is None:
                raise OnnxFileError("cut short inside a number")
            yield number, wire, value
            continue
        if wire == _LENGTH:
            length = _varint(read)
            if length is None:
                raise OnnxFileError("cut short inside a length")
        elif wire in (_FIXED64, _FIXED32):
            length = 8 if wire == _FIXED64 else 4
        else:
            raise OnnxFileError(f"field {number} has wire type {wire}, which ONNX never uses")
        start = read.tell()
        if start + length > end:
            raise OnnxFileError(f"field {number} of {length} bytes goes past the end")
        yield number, wire, length
        read.seek(start + length)


def _entry(read: BinaryIO, length: int) -> tuple[str, str]:
    """One StringStringEntryProto of `length` bytes at the current offset."""
    out = {1: "", 2: ""}
    for number, wire, size in _fields(read, read.tell() + length):
        if wire == _LENGTH and number in out:
            try:
                out[number] = read.read(size).decode("utf-8")
            except UnicodeDecodeError:
                raise OnnxFileError("a metadata entry is not UTF-8") from None
    return out[1], out[2]


def read_metadata(path: Path) -> dict[str, str]:
    """The `metadata_props` of the ONNX file `path` (its graph skipped, not read);
    OnnxFileError when the file is not an ONNX model, OSError when it cannot be read."""
    metadata: dict[str, str] = {}
    seen: set[int] = set()
    with path.open("rb") as read:
        end = read.seek(0, 2)
        read.seek(0)
        for number, wire, value in _fields(read, end):
            seen.add(number)
            if number == _METADATA and wire == _LENGTH:
                key, text = _entry(read, value)
                metadata[key] = text
    if _GRAPH not in seen or _IR_VERSION not in seen:
        raise OnnxFileError("no graph or no IR version: not an ONNX model")
    return metadata


def read_graph_size(path: Path) -> GraphSize:
    """The nodes and initializer bytes of the ONNX file's graph (one pass over the graph's
    fields, each node and initializer skipped by its length)."""
    nodes, weights = 0, 0
    with path.open("rb") as read:
        end = read.seek(0, 2)
        read.seek(0)
        for number, wire, value in _fields(read, end):
            if number != _GRAPH or wire != _LENGTH:
                continue
            for field, kind, length in _fields(read, read.tell() + value):
                if kind == _LENGTH and field == _GRAPH_NODE:
                    nodes += 1
                elif kind == _LENGTH and field == _GRAPH_INITIALIZER:
                    weights += length
    return GraphSize(nodes, weights)
