"""The QTM real-time protocol as this package uses it: framing, packet and component types.

Qualisys, "QTM Real-time Server Protocol Documentation" (docs.qualisys.com/qtm-rt-protocol),
checked against the ``qtm-rt`` package (Qualisys' Python SDK, 3.1: ``qtm_rt/packet.py``
``QRTPacketType``, ``QRTComponentType``, ``QRTEvent`` and the ``RT*`` structs;
``qtm_rt/qrt.py`` ``connect(port=22223)``):

- every packet: a little-endian header, u32 size (the header's 8 bytes included) and u32
  type (0 error, 1 command, 2 XML, 3 data, 4 no more data, 6 event), then the body; command,
  error and XML bodies are NUL-terminated strings, an event body one byte (1: connected);
- a data packet: i64 timestamp [us], u32 frame number, u32 component count, then components
  of u32 size (its 8-byte header included) and u32 type (5: 6D, 6: 6D Euler);
- a 6D component: i32 body count, u16 2-D drop rate, u16 out-of-sync rate, then per body
  x, y, z [mm] as float32 and the 3x3 rotation matrix as 9 float32 in column-major order
  (NaN while the body is not tracked); 6D Euler: three angles [deg] instead of the matrix;
- ``GetParameters 6D`` answers XML whose ``*/Body/Name`` elements name the rigid bodies in
  the order of the data packets (the protocol 1.21+ layout).

The driver parses packets with qtm-rt's own parser; it uses the port, the parameter XML and
the matrix order from here. The emulator frames its packets with this module, and its bytes
are pinned by hand in the tests, so qtm-rt itself checks what both assume. No ROS here.
"""

from __future__ import annotations

import struct
from typing import Any
import xml.etree.ElementTree as ET

import numpy as np

#: QTM's RT server port for little-endian clients (the one qtm-rt speaks).
DEFAULT_PORT = 22223

PACKET_ERROR = 0
PACKET_COMMAND = 1
PACKET_XML = 2
PACKET_DATA = 3
PACKET_NO_MORE_DATA = 4
PACKET_EVENT = 6
COMPONENT_6D = 5
COMPONENT_6D_EULER = 6
EVENT_CONNECTED = 1
#: The command packet QTM sends first on every connection.
WELCOME = 'QTM RT Interface connected'

#: Packet header: u32 size (header included), u32 type.
HEADER = struct.Struct('<II')
#: Data packet header: i64 timestamp [us], u32 frame number, u32 component count.
DATA_HEADER = struct.Struct('<qII')
#: Component header: u32 size (header included), u32 type.
COMPONENT_HEADER = struct.Struct('<II')
#: 6D component header: i32 body count, u16 2-D drop rate, u16 out-of-sync rate.
SIX_D_HEADER = struct.Struct('<ihh')
#: One 6D body: x, y, z [mm], rotation matrix column-major.
SIX_D_BODY = struct.Struct('<3f9f')
#: One 6D Euler body: x, y, z [mm], three angles [deg].
SIX_D_EULER_BODY = struct.Struct('<3f3f')


def packet(ptype: int, body: bytes) -> bytes:
    """Encode one packet: header (size including itself, type) and body."""
    return HEADER.pack(HEADER.size + len(body), ptype) + body


def text_packet(ptype: int, text: str) -> bytes:
    """Encode a command, error or XML packet: the text NUL-terminated."""
    return packet(ptype, text.encode() + b'\0')


def matrix_from_column_major(values: Any) -> np.ndarray:
    """Return the 3x3 rotation matrix of QTM's 9 column-major floats."""
    return np.asarray(values, dtype=float).reshape(3, 3).T


def body_names(xml_text: Any) -> list[str]:
    """Rigid body names of a ``GetParameters 6D`` answer, in data-packet order."""
    text = xml_text.decode(errors='replace') if isinstance(xml_text, bytes) else xml_text
    root = ET.fromstring(text.rstrip('\0'))
    return [(e.text or '').strip() for e in root.findall('*/Body/Name')]
