"""Protocol 2.0 framing, held against the ROBOTIS e-manual's packets and the SDK's own CRC and stuffing."""

from __future__ import annotations

from dynamixel_sdk import PacketHandler
from hypothesis import given, settings
from hypothesis import strategies as st

from simnav.hardware.protocol import (
    CRC_TABLE,
    CrcMismatch,
    Instruction,
    Packet,
    PacketParser,
    crc16,
    instruction_packet,
    status_packet,
    stuff,
    unstuff,
)

SDK = PacketHandler(2.0)


def hexbytes(text: str) -> bytes:
    return bytes.fromhex(text)


def test_e_manual_packets_are_reproduced_byte_for_byte():
    assert instruction_packet(1, Instruction.PING) == hexbytes("FF FF FD 00 01 03 00 01 19 4E")
    # ping status of an XM430-W210 (model 1030) with firmware 38
    assert status_packet(1, 0, bytes([0x06, 0x04, 0x26])) == hexbytes("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D")
    assert instruction_packet(1, Instruction.READ, hexbytes("84 00 04 00")) == \
        hexbytes("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")
    assert instruction_packet(0xFE, Instruction.SYNC_READ, hexbytes("84 00 04 00 01 02")) == \
        hexbytes("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA")
    sync_write = instruction_packet(0xFE, Instruction.SYNC_WRITE,
                                    hexbytes("74 00 04 00 01 96 00 00 00 02 AA 00 00 00"))
    assert sync_write[:8] == hexbytes("FF FF FD 00 FE 11 00 83") and sync_write[-2:] == hexbytes("82 87")


def test_crc_table_is_the_sdk_table():
    assert CRC_TABLE[:4] == (0x0000, 0x8005, 0x800F, 0x000A)
    assert all(crc16(bytes([i, 0])) == SDK.updateCRC(0, [i, 0], 2) for i in range(256))


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=64))
def test_crc_matches_the_sdk_on_any_bytes(data):
    assert crc16(data) == SDK.updateCRC(0, list(data), len(data))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from([0xFF, 0xFD, 0x00, 0x01]), max_size=40))
def test_stuffing_matches_the_sdk_and_round_trips(params):
    body = bytes([Instruction.WRITE, *params])
    length = len(body) + 2
    sdk_packet = [0xFF, 0xFF, 0xFD, 0x00, 0x01, length & 0xFF, length >> 8, *body, 0, 0]
    sdk_packet = SDK.addStuffing(sdk_packet)
    ours = instruction_packet(1, Instruction.WRITE, bytes(params))
    assert bytes(sdk_packet[:-2]) == ours[:-2]  # same stuffed bytes and LEN (the SDK fills in the CRC later)
    assert unstuff(stuff(body)) == body


def test_stuffing_inserts_fd_after_every_ff_ff_fd():
    assert stuff(hexbytes("FF FF FD 00")) == hexbytes("FF FF FD FD 00")
    assert stuff(hexbytes("FF FF FD FF FF FD")) == hexbytes("FF FF FD FD FF FF FD FD")
    assert unstuff(hexbytes("FF FF FD FD FD")) == hexbytes("FF FF FD FD")


def test_parser_resynchronises_after_garbage_and_split_packets():
    ping = instruction_packet(1, Instruction.PING)
    write = instruction_packet(2, Instruction.WRITE, hexbytes("40 00 01"))
    stream = b"\x00\xff\xff\xfd" + ping + b"\xff\xff" + write + b"\x13\x37"
    whole = PacketParser().feed(stream)
    parser = PacketParser()
    bytewise = [p for k in range(len(stream)) for p in parser.feed(stream[k:k + 1])]
    assert [(p.dxl_id, p.instruction, p.params) for p in whole] == [(1, 1, b""), (2, 3, hexbytes("40 00 01"))]
    assert bytewise == whole


def test_parser_reports_crc_mismatches_and_unstuffs_parameters():
    bad = bytearray(instruction_packet(1, Instruction.PING))
    bad[-1] ^= 0x01
    stuffed = instruction_packet(1, Instruction.READ, hexbytes("FF FF FD 00"))
    assert hexbytes("FF FF FD FD 00") in stuffed
    out = PacketParser().feed(bytes(bad) + stuffed)
    assert isinstance(out[0], CrcMismatch) and out[0].dxl_id == 1
    assert isinstance(out[-1], Packet) and out[-1].params == hexbytes("FF FF FD 00")


def test_parser_drops_a_frame_that_never_completes():
    parser = PacketParser()
    assert parser.feed(hexbytes("FF FF FD 00 01 F0 03 02")) == []  # claims 1008 bytes
    parser.drop_partial()
    assert parser.feed(instruction_packet(1, Instruction.PING))[0].instruction == Instruction.PING


def test_status_packets_decode_with_their_error_byte():
    packet = PacketParser().feed(status_packet(2, 0x87, hexbytes("01 02")))[0]
    assert packet.is_status and packet.dxl_id == 2 and packet.error == 0x87 and packet.params == hexbytes("01 02")


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.binary(max_size=12).map(lambda b: b.replace(b"\xff", b"")),
                          st.integers(0, 252), st.binary(max_size=20)), min_size=1, max_size=6),
       st.integers(1, 7))
def test_every_packet_between_garbage_is_recovered_in_any_chunking(items, chunk):
    packets = [instruction_packet(i, Instruction.WRITE, params) for _, i, params in items]
    stream = b"".join(garbage + packet for (garbage, _, _), packet in zip(items, packets))
    parser = PacketParser()
    out = [p for k in range(0, len(stream), chunk) for p in parser.feed(stream[k:k + chunk])]
    assert [p.raw for p in out] == packets
    assert [p.params for p in out] == [params for _, _, params in items]
