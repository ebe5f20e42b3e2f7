"""The clip-on device's serial protocol (spec: proto/device_protocol.md): COBS + CRC-32
framing, packet layouts, a streaming parser with fault counters, and a pseudo-terminal
device emulator with fault injection. Shared by the sensor gateway and the bench."""

from tiplog.devproto.framing import FrameError, cobs_decode, cobs_encode, decode_chunk, encode_frame
from tiplog.devproto.packets import (
    PROTOCOL_VERSION,
    HelloPacket,
    Packet,
    PacketType,
    TofPacket,
    Vec3Packet,
    decode_body,
    encode_packet,
    encode_packet_frame,
)
from tiplog.devproto.parser import FAULT_KINDS, StreamParser

__all__ = [
    "FAULT_KINDS",
    "PROTOCOL_VERSION",
    "FrameError",
    "HelloPacket",
    "Packet",
    "PacketType",
    "StreamParser",
    "TofPacket",
    "Vec3Packet",
    "cobs_decode",
    "cobs_encode",
    "decode_body",
    "decode_chunk",
    "encode_frame",
    "encode_packet",
    "encode_packet_frame",
]
