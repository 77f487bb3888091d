"""The QTM RT protocol module against the numbers of Qualisys' sources, typed here by hand.

Sources: Qualisys, "QTM Real-time Server Protocol Documentation" (docs.qualisys.com/
qtm-rt-protocol) and the qtm-rt package 3.1 (qtm_rt/packet.py: QRTPacketType,
QRTComponentType, QRTEvent, RTheader, RTDataQRTPacket, RTComponentData, RT6DComponent,
RT6DBodyPosition, RT6DBodyRotation, RT6DBodyEuler; qtm_rt/qrt.py: connect(port=22223)).
The installed qtm-rt is asked too, so that an upgrade that moved a number is seen.
"""

from __future__ import annotations

import numpy as np
from qtm_rt import packet as qrt
import pytest

from enbarr_plugins.mocap import qtm_protocol as protocol

#: (name, value, where the number is written), typed from the sources above.
DOCUMENTED = [
    ('DEFAULT_PORT', 22223, 'protocol doc: little-endian port 22223; qrt.py connect(port=22223)'),
    ('PACKET_ERROR', 0, 'packet.py QRTPacketType.PacketError'),
    ('PACKET_COMMAND', 1, 'packet.py QRTPacketType.PacketCommand'),
    ('PACKET_XML', 2, 'packet.py QRTPacketType.PacketXML'),
    ('PACKET_DATA', 3, 'packet.py QRTPacketType.PacketData'),
    ('PACKET_NO_MORE_DATA', 4, 'packet.py QRTPacketType.PacketNoMoreData'),
    ('PACKET_EVENT', 6, 'packet.py QRTPacketType.PacketEvent'),
    ('COMPONENT_6D', 5, 'packet.py QRTComponentType.Component6d'),
    ('COMPONENT_6D_EULER', 6, 'packet.py QRTComponentType.Component6dEuler'),
    ('EVENT_CONNECTED', 1, 'packet.py QRTEvent.EventConnected'),
]

#: (struct name, format, qtm-rt's struct of the same layout)
LAYOUTS = [
    ('HEADER', '<II', qrt.RTheader),                     # size (header included), type
    ('DATA_HEADER', '<qII', qrt.RTDataQRTPacket),        # timestamp [us], frame, components
    ('COMPONENT_HEADER', '<II', qrt.RTComponentData),    # size (header included), type
    ('SIX_D_HEADER', '<ihh', qrt.RT6DComponent.format),  # bodies, 2-D drop, out of sync
]


def test_constants_are_the_documents():
    assert [(n, getattr(protocol, n)) for n, _, _ in DOCUMENTED] == [
        (n, v) for n, v, _ in DOCUMENTED]


def test_the_installed_qtm_rt_agrees_with_the_typed_numbers():
    assert qrt.QRTPacketType.PacketError.value == 0
    assert qrt.QRTPacketType.PacketCommand.value == 1
    assert qrt.QRTPacketType.PacketXML.value == 2
    assert qrt.QRTPacketType.PacketData.value == 3
    assert qrt.QRTPacketType.PacketNoMoreData.value == 4
    assert qrt.QRTPacketType.PacketEvent.value == 6
    assert qrt.QRTComponentType.Component6d.value == 5
    assert qrt.QRTComponentType.Component6dEuler.value == 6
    assert qrt.QRTEvent.EventConnected.value == 1


@pytest.mark.parametrize('name, fmt, theirs', LAYOUTS, ids=[n for n, _, _ in LAYOUTS])
def test_layouts_are_the_documents(name, fmt, theirs):
    assert getattr(protocol, name).format == fmt == theirs.format


def test_a_six_d_body_is_position_then_a_column_major_matrix():
    # x, y, z [mm] (RT6DBodyPosition <3f), then 9 floats (RT6DBodyRotation <9f)
    assert protocol.SIX_D_BODY.format == '<3f9f'
    assert qrt.RT6DBodyPosition.format.size + qrt.RT6DBodyRotation.format.size == 48
    assert protocol.SIX_D_EULER_BODY.format == '<3f3f'
    # column-major: the floats a, b, c are the first column
    r = protocol.matrix_from_column_major([1, 2, 3, 4, 5, 6, 7, 8, 9])
    assert r[:, 0].tolist() == [1.0, 2.0, 3.0] and r[0].tolist() == [1.0, 4.0, 7.0]


def test_packets_are_framed_as_the_document_says():
    # 'Version 1.25' + NUL = 13 bytes: size 21 (0x15) including the 8-byte header, type 1
    assert protocol.text_packet(1, 'Version 1.25') == (
        bytes.fromhex('15000000 01000000') + b'Version 1.25\0')
    assert protocol.packet(6, b'\x01') == bytes.fromhex('09000000 06000000 01')


def test_body_names_come_in_data_order():
    xml_text = ('<QTM_Parameters_Ver_1.25><The_6D><Body><Name>CSS</Name></Body>'
                '<Body><Name> buoy </Name></Body></The_6D></QTM_Parameters_Ver_1.25>\0')
    assert protocol.body_names(xml_text.encode()) == ['CSS', 'buoy']
    assert np.isfinite(protocol.matrix_from_column_major(np.eye(3).ravel())).all()
