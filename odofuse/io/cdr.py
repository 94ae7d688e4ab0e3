"""One topic's ROS 2 messages decoded at once, as columns (the bag reader's fast path).

rosbags deserialises a message at a time into Python objects: about 25 us for an ``Imu``
here, a second for a 13-minute bag of 39,000 messages. But a topic's messages almost always
share one layout (the same ``frame_id``, the same joint names, the same sequence lengths) and
differ only in their numbers. So :func:`decode` walks the layout once, on the first message,
with the CDR rules that rosbags' own deserialisers follow (every field at its natural
alignment, counted from the end of the 4-byte encapsulation header; a string or a sequence is
a ``uint32`` length, then its elements). It then checks that every message carries the same
bytes wherever the layout depends on them: the header, every length, every string. Each wanted
number is then one strided view over all the messages.

The first message is also deserialised by rosbags, and the columns must give its values;
otherwise :func:`decode` returns None, and so it does for messages of unequal length, a
big-endian or unknown encapsulation, a field type it does not walk, or any layout that
differs between messages. The caller then deserialises message by message
(:mod:`odofuse.io.bags`), so the two paths give the same numbers, and only their speed
differs (``tests/test_ros2.py``).
"""

from __future__ import annotations

import struct

import numpy as np

_DTYPES = {
    "bool": "?",
    "byte": "u1",
    "char": "u1",
    "int8": "i1",
    "uint8": "u1",
    "int16": "<i2",
    "uint16": "<u2",
    "int32": "<i4",
    "uint32": "<u4",
    "int64": "<i8",
    "uint64": "<u8",
    "float32": "<f4",
    "float64": "<f8",
}
_LITTLE_ENDIAN_CDR = b"\x00\x01"
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4  # rosbags.interfaces.Nodetype


class _Unsupported(Exception):
    """A field type the walk does not cover (wide strings, float128)."""


def _aligned(pos: int, size: int) -> int:
    return (pos + size - 1) & -size


def _alignment(desc, ts) -> int:
    """Alignment of a field (rosbags.serde.utils.align)."""
    node, arg = desc[0], desc[1]
    if node == _BASE:
        return 4 if arg[0] == "string" else _size(arg[0])
    if node == _NAME:
        return _alignment(ts.get_msgdef(arg).fields[0][1], ts)
    if node == _ARRAY:
        return _alignment(arg[0], ts)
    return 4  # a sequence starts with its uint32 length


def _size(typ: str) -> int:
    if typ not in _DTYPES:
        raise _Unsupported(typ)
    return np.dtype(_DTYPES[typ]).itemsize


class _Walk:
    """The layout of one message: ``leaves`` ``{path: ("num", offset, dtype, count) or ("text",
    value)}`` (``count`` None for a scalar), ``fixed`` the byte ranges the layout rests on."""

    def __init__(self, data: bytes, ts):
        self.data, self.ts = data, ts
        self.leaves: dict[str, tuple] = {}
        self.fixed: list[tuple[int, int]] = []

    def _uint32(self, pos: int) -> int:
        self.fixed.append((pos, pos + 4))
        return struct.unpack_from("<I", self.data, pos)[0]

    def _string(self, pos: int) -> tuple[str, int]:
        pos = _aligned(pos, 4)
        n, start = self._uint32(pos), pos + 4
        self.fixed.append((start, start + n))
        return bytes(self.data[start : start + n - 1]).decode(), start + n

    def fields(self, fields, pos: int, prefix: str) -> int:
        for name, desc in fields:
            pos = self.field(desc, _aligned(pos, _alignment(desc, self.ts)), prefix + name)
        return pos

    def field(self, desc, pos: int, path: str) -> int:
        node, arg = desc[0], desc[1]
        if node == _NAME:
            return self.fields(self.ts.get_msgdef(arg).fields, pos, path + ".")
        if node == _BASE:
            if arg[0] == "string":
                text, pos = self._string(pos)
                self.leaves[path] = ("text", text)
                return pos
            size = _size(arg[0])
            self.leaves[path] = ("num", pos, _DTYPES[arg[0]], None)
            return pos + size
        sub, count = arg
        if node == _SEQUENCE:
            count = self._uint32(pos)
            pos += 4
        if sub[0] == _BASE and sub[1][0] == "string":
            texts = []
            for _ in range(count):
                text, pos = self._string(pos)
                texts.append(text)
            self.leaves[path] = ("text", tuple(texts))
            return pos
        if sub[0] == _BASE:
            if count:
                pos = _aligned(pos, _size(sub[1][0]))
            self.leaves[path] = ("num", pos, _DTYPES[sub[1][0]], count)
            return pos + count * _size(sub[1][0])
        for k in range(count):  # messages: each at its alignment
            pos = self.field(sub, _aligned(pos, _alignment(sub, self.ts)), f"{path}.{k}")
        return pos


def decode(raws: list, msgtype: str, ts, wanted) -> dict | None:
    """``{path: column}`` of the ``wanted`` fields (dotted paths, e.g. ``header.stamp.sec``) of
    the CDR messages ``raws`` of ``msgtype`` (``ts``: the reader's typestore), or None when they
    do not share one layout (module docstring).

    A number is an array ``(N,)`` of its CDR type, a fixed array or a sequence ``(N, k)``, a
    string (or a list of strings) a list of N equal values (tuples of strings)."""
    n = len(raws)
    if not n:
        return None
    first = bytes(raws[0])
    width = len(first)
    if width < 4 or first[:2] != _LITTLE_ENDIAN_CDR or any(len(r) != width for r in raws):
        return None
    walk = _Walk(memoryview(first)[4:], ts)
    try:
        end = walk.fields(ts.get_msgdef(msgtype).fields, 0, "")
    except (_Unsupported, struct.error, UnicodeDecodeError, KeyError, IndexError):
        return None
    if not end + 4 <= width <= end + 7 or any(p not in walk.leaves for p in wanted):
        return None
    rows = np.frombuffer(b"".join(raws), dtype=np.uint8).reshape(n, width)
    fixed = np.concatenate([np.arange(4)] + [np.arange(a + 4, b + 4) for a, b in walk.fixed])
    if not np.array_equal(rows[:, fixed], np.broadcast_to(rows[0, fixed], (n, fixed.size))):
        return None
    out: dict = {}
    for path in wanted:
        leaf = walk.leaves[path]
        if leaf[0] == "text":
            out[path] = [leaf[1]] * n
            continue
        _, off, dtype, count = leaf
        dt = np.dtype(dtype)
        if count == 0:  # an empty sequence
            out[path] = np.empty((n, 0), dtype=dt)
            continue
        block = np.ascontiguousarray(rows[:, off + 4 : off + 4 + dt.itemsize * (count or 1)])
        out[path] = block.view(dt)[:, 0] if count is None else block.view(dt)
    return out if _agrees(out, ts.deserialize_cdr(first, msgtype)) else None


def _agrees(columns: dict, msg) -> bool:
    """Whether the first row of ``columns`` is rosbags' deserialisation ``msg``."""
    for path, col in columns.items():
        value = msg
        for name in path.split("."):
            value = getattr(value, name)
        if isinstance(col, list):
            if (tuple(value) if isinstance(col[0], tuple) else value) != col[0]:
                return False
        elif not np.array_equal(np.asarray(value), col[0], equal_nan=col.dtype.kind == "f"):
            return False
    return True
