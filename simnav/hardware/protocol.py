"""Dynamixel Protocol 2.0 framing, byte exact: CRC-16, byte stuffing, instruction/status packets, a stream parser.

Standard library only. The bridge talks through the real ``dynamixel_sdk``; this module is the other side of the
wire (the virtual bus) and the reference the tests hold the SDK's packets against.

Packet layout (ROBOTIS e-manual, Protocol 2.0)::

    instruction:  FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAM...       | CRC_L CRC_H    LEN = nparams + 3
    status:       FF FF FD 00 | ID | LEN_L LEN_H | 0x55 | ERR | PARAM... | CRC_L CRC_H    LEN = nparams + 4

Byte stuffing: from INST to the last parameter, every ``FF FF FD`` gets an extra ``FD``; LEN counts the stuffed
bytes and the CRC covers the stuffed packet from the header to the last parameter.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import IntEnum

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
MAX_PACKET_BYTES = 1024
"""Longest packet accepted on receive (the SDK's TX/RX buffer size), bytes."""


class Instruction(IntEnum):
    """Protocol 2.0 instruction codes."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class ErrorCode(IntEnum):
    """The low 7 bits of a status packet's error byte."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


ALERT_BIT = 0x80
"""Set in a status packet's error byte while the device has a hardware error (see register 70)."""


def _crc_table() -> tuple[int, ...]:
    """T[i] = CRC-16 (poly 0x8005, MSB first, init 0) of the byte i followed by zeros: 0x0000, 0x8005, 0x800F..."""
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


CRC_TABLE = _crc_table()


def crc16(data: Iterable[int], crc: int = 0) -> int:
    """CRC-16 of Protocol 2.0 (poly 0x8005, init 0, no reflection, no final XOR), continuing from ``crc``."""
    table = CRC_TABLE
    for byte in data:
        crc = ((crc << 8) ^ table[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes, prefix: bytes = b"\x00\x00") -> bytes:
    """Add a ``FD`` after every ``FF FF FD`` in ``body`` (INST..last PARAM); ``prefix`` is the two bytes before
    ``body`` on the wire (LEN_L LEN_H of the unstuffed packet), which the SDK also looks back into."""
    out = bytearray()
    window = bytearray(prefix[-2:])
    for byte in body:
        out.append(byte)
        if byte == 0xFD and window[-2:] == b"\xff\xff":
            out.append(0xFD)
        window.append(byte)
        del window[:-2]
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Remove the ``FD`` added after every ``FF FF FD`` (the inverse of :func:`stuff`)."""
    out = bytearray()
    skip_next = False
    for k, byte in enumerate(body):
        if skip_next:
            skip_next = False
            if byte == 0xFD:
                continue
        out.append(byte)
        if byte == 0xFD and k >= 2 and body[k - 2:k] == b"\xff\xff" and k + 1 < len(body) and body[k + 1] == 0xFD:
            skip_next = True
    return bytes(out)


def _frame(dxl_id: int, body: bytes) -> bytes:
    """Header, ID, LEN, stuffed body and CRC around an unstuffed ``body`` (INST [ERR] PARAM...)."""
    raw_len = len(body) + 2
    stuffed = stuff(body, bytes([raw_len & 0xFF, raw_len >> 8]))
    length = len(stuffed) + 2
    packet = HEADER + bytes([dxl_id & 0xFF, length & 0xFF, length >> 8]) + stuffed
    crc = crc16(packet)
    return packet + bytes([crc & 0xFF, crc >> 8])


def instruction_packet(dxl_id: int, instruction: int, params: bytes = b"") -> bytes:
    """An instruction packet, stuffed and with its CRC."""
    return _frame(dxl_id, bytes([instruction]) + bytes(params))


def status_packet(dxl_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet (instruction 0x55), stuffed and with its CRC."""
    return _frame(dxl_id, bytes([Instruction.STATUS, error & 0xFF]) + bytes(params))


@dataclass(frozen=True)
class Packet:
    """One received packet, unstuffed. ``params`` excludes the error byte of a status packet."""

    dxl_id: int
    instruction: int
    params: bytes
    raw: bytes
    error: int = 0

    @property
    def is_status(self) -> bool:
        return self.instruction == Instruction.STATUS


@dataclass(frozen=True)
class CrcMismatch:
    """A complete frame whose CRC did not match (the device answers with a CRC error if it is addressed)."""

    dxl_id: int
    raw: bytes


class PacketParser:
    """Incremental parser of a byte stream into packets; resynchronises on the header after garbage.

    Frames with an impossible length are skipped one byte at a time; a frame that stays incomplete is dropped by
    :meth:`drop_partial` (the device's inter-packet timeout).
    """

    def __init__(self, max_packet_bytes: int = MAX_PACKET_BYTES) -> None:
        self._buf = bytearray()
        self._max = max_packet_bytes

    @property
    def pending(self) -> int:
        """Bytes held while waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Packet | CrcMismatch]:
        """Add bytes; return the packets (and CRC mismatches) completed by them, in order."""
        self._buf += data
        out: list[Packet | CrcMismatch] = []
        while True:
            item = self._next()
            if item is None:
                return out
            out.append(item)

    def drop_partial(self) -> None:
        """Forget an incomplete frame: skip its first byte and look for the next header."""
        if self._buf:
            del self._buf[0]
            self._seek_header()

    def _seek_header(self) -> bool:
        k = self._buf.find(HEADER)
        if k < 0:  # keep a tail that may be the start of a header
            keep = next((n for n in (3, 2, 1) if n <= len(self._buf) and HEADER.startswith(bytes(self._buf[-n:]))),
                        0)
            del self._buf[:len(self._buf) - keep]
            return False
        del self._buf[:k]
        return True

    def _next(self) -> Packet | CrcMismatch | None:
        while True:
            if not self._seek_header() or len(self._buf) < 7:
                return None
            length = self._buf[5] | (self._buf[6] << 8)
            if length < 3 or length + 7 > self._max or self._buf[4] == 0xFF:
                del self._buf[0]
                continue
            total = length + 7
            if len(self._buf) < total:
                return None
            frame = bytes(self._buf[:total])
            if crc16(frame[:-2]) != (frame[-2] | (frame[-1] << 8)):
                del self._buf[0]
                return CrcMismatch(frame[4], frame)
            del self._buf[:total]
            return _decode(frame)

    def reset(self) -> None:
        """Drop everything buffered."""
        self._buf.clear()


def _decode(frame: bytes) -> Packet:
    body = unstuff(frame[7:-2])
    instruction = body[0]
    if instruction == Instruction.STATUS and len(body) >= 2:
        return Packet(frame[4], instruction, body[2:], frame, error=body[1])
    return Packet(frame[4], instruction, body[1:], frame)


def le_bytes(value: int, size: int) -> bytes:
    """``value`` as ``size`` little-endian bytes (negative values as two's complement)."""
    return (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")


def from_le(data: bytes, signed: bool = False) -> int:
    """Little-endian bytes as an integer (two's complement when ``signed``)."""
    return int.from_bytes(data, "little", signed=signed)
