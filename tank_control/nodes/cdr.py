"""Signal messages as CDR bytes, encoded and decoded directly (no rclpy message objects).

A lockstep tick is a handful of small messages per process, and building rclpy message objects
(``JointState`` → ``Header`` → ``Time``, each with its Python ``__init__`` and checked setters)
and converting them to C and back costs as much as the DDS hop itself (py-spy, bench/RESULTS.md
"Lockstep"). The nodes therefore publish pre-encoded bytes (``Publisher.publish`` takes
``bytes``) and take their hot-path inputs as raw bytes (``create_subscription(..., raw=True)``).

Encoding: plain CDR (XCDR1), little endian, as ``rclpy.serialization.serialize_message`` writes
it (zeros as padding); alignment counts from the end of the 4-byte encapsulation header, float64
on 8 bytes. Decoding also reads XCDR2 (float64 on 4 bytes) and big-endian data, as the
encapsulation header says. Layout of ``sensor_msgs/msg/JointState``: header (stamp: int32 sec,
uint32 nanosec; frame_id: string), name (sequence<string>), position, velocity, effort
(sequence<float64>). A CDR string is a uint32 length counting its NUL, the bytes, the NUL.
"""
from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

NS_PER_S = 1_000_000_000
#: encapsulation header: plain CDR, little endian
CDR_LE = b'\x00\x01\x00\x00'
_STAMP_LE = struct.Struct('<iI')
_U32 = {'<': struct.Struct('<I'), '>': struct.Struct('>I')}
_STAMP = {'<': struct.Struct('<iI'), '>': struct.Struct('>iI')}


def _cdr_string(text: str, offset: int) -> tuple[bytes, int]:
    """A CDR string (4-aligned length with the NUL, bytes, NUL) at body ``offset``."""
    data = text.encode() + b'\x00'
    pad = -offset % 4
    out = b'\x00' * pad + struct.pack('<I', len(data)) + data
    return out, offset + len(out)


class JointStateCdr:
    """``sensor_msgs/msg/JointState`` with fixed ``name`` and ``frame_id`` (no velocity or
    effort) serialized directly: one ``struct`` pack per message."""

    def __init__(self, names: Sequence[str], frame_id: str = '') -> None:
        self.names = tuple(names)
        offset = 8                                   # header.stamp: int32 sec, uint32 nanosec
        frame, offset = _cdr_string(frame_id, offset)
        pad = -offset % 4
        parts = [frame, b'\x00' * pad + struct.pack('<I', len(names))]
        offset += pad + 4
        for name in names:
            text, offset = _cdr_string(name, offset)
            parts.append(text)
        pad = -offset % 4
        parts.append(b'\x00' * pad + struct.pack('<I', len(names)))
        offset += pad + 4
        if names:
            parts.append(b'\x00' * (-offset % 8))
            offset += -offset % 8
        middle = b''.join(parts)
        offset += 8 * len(names)
        tail = b'\x00' * (-offset % 4) + struct.pack('<II', 0, 0)   # velocity, effort
        # one Struct for the whole message: header, stamp, the fixed middle, positions, tail
        self._struct = struct.Struct(f'<4siI{len(middle)}s{len(names)}d{len(tail)}s')
        self._middle, self._tail = middle, tail

    def encode(self, sec: int, nanosec: int, positions: Sequence[float]) -> bytes:
        return self._struct.pack(CDR_LE, sec, nanosec, self._middle, *positions, self._tail)

    def encode_ns(self, t_ns: int, positions: Sequence[float] | np.ndarray) -> bytes:
        """The message stamped ``t_ns`` [ns] (exact)."""
        sec, nanosec = divmod(int(t_ns), NS_PER_S)
        return self._struct.pack(CDR_LE, sec, nanosec, self._middle, *positions, self._tail)


def clock_cdr(sec: int, nanosec: int) -> bytes:
    """``rosgraph_msgs/msg/Clock`` as plain little-endian CDR."""
    return CDR_LE + _STAMP_LE.pack(sec, nanosec)


def clock_cdr_ns(t_ns: int) -> bytes:
    """``rosgraph_msgs/msg/Clock`` for the instant ``t_ns`` [ns] (exact)."""
    return CDR_LE + _STAMP_LE.pack(*divmod(int(t_ns), NS_PER_S))


#: ``builtin_interfaces/msg/Time`` for the instant ``t_ns`` [ns] (exact): the same bytes as a
#: ``Clock``, whose only field is one ``Time``.
time_cdr_ns = clock_cdr_ns


def cdr_stamp_ns(data: bytes) -> int:
    """The first ``builtin_interfaces/Time`` of a CDR message (header.stamp of a JointState,
    the clock of a Clock, a Time itself) [ns], without deserialising it."""
    sec, nanosec = _STAMP['<' if data[1] & 1 else '>'].unpack_from(data, 4)
    return sec * NS_PER_S + nanosec


def signal_from_cdr(data: bytes, max_names: int | None = None
                    ) -> tuple[int, str, tuple[str, ...], tuple[float, ...]]:
    """``header.stamp`` [ns], ``header.frame_id``, ``name`` and ``position`` of a CDR
    ``sensor_msgs/JointState``. Raises ``ValueError`` on data too short for what it announces,
    or (``max_names``) announcing more names than that — before decoding any of them."""
    try:
        endian = '<' if data[1] & 1 else '>'
        wide = 8 if data[1] in (0, 1) else 4
        u32 = _U32[endian].unpack_from
        sec, nanosec = _STAMP[endian].unpack_from(data, 4)
        (length,) = u32(data, 12)                        # header.frame_id
        frame_id = data[16:15 + length].decode() if length > 1 else ''
        offset = 16 + length
        offset += -(offset - 4) % 4
        (count,) = u32(data, offset)
        offset += 4
        if max_names is not None and count > max_names:
            raise ValueError(f'{count} channel names, at most {max_names} taken')
        names = []
        for _ in range(count):
            offset += -(offset - 4) % 4
            (length,) = u32(data, offset)
            end = offset + 3 + length
            if end > len(data):
                raise ValueError('a name runs past the end')
            names.append(data[offset + 4:end].decode())
            offset = end + 1
        offset += -(offset - 4) % 4
        (count,) = u32(data, offset)
        offset += 4
        if count:
            offset += -(offset - 4) % wide
        values = struct.unpack_from(f'{endian}{count}d', data, offset)
    except (struct.error, IndexError, UnicodeDecodeError) as exc:
        raise ValueError(f'malformed CDR JointState ({exc})') from None
    return sec * NS_PER_S + nanosec, frame_id, tuple(names), values


def joint_state_from_cdr(data: bytes) -> tuple[int, tuple[str, ...], tuple[float, ...]]:
    """``header.stamp`` [ns], ``name`` and ``position`` of a CDR ``sensor_msgs/JointState``
    (``signal_from_cdr`` without the frame id)."""
    stamp, _, names, values = signal_from_cdr(data)
    return stamp, names, values
