"""``enbarr check-device qualisys --host HOST [--name BODY]``: the 6D bodies and one pose.

With ``--host emulated`` it starts the QTM emulator in this process and checks against it
(the command's own test). Apart from the driver so that the driver never imports its
emulator.
"""

from __future__ import annotations

import asyncio
import logging
import math
from typing import Any

import qtm_rt

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins.check import CheckTarget, device_endpoint
from enbarr_plugins.mocap.qtm_emulator import QtmEmulator
from enbarr_plugins.mocap.qtm_protocol import DEFAULT_PORT
from enbarr_plugins.mocap.qualisys import (
    body_index, open_session, parse_host, pose_of, qtm_said, read_bodies, tcp_address)

#: The protocol version the check negotiates.
VERSION = '1.25'


def check_device(target: CheckTarget) -> list[str]:
    """Connect, list the 6D bodies, print one pose of ``--name`` (the first body if none)."""
    if not target.host:
        raise DeviceError("qualisys: give --host (the QTM computer's address) or emulated")
    host, port = parse_host(target.host)
    # qtm-rt logs its own lines (connected, disconnected, the error it met); the check says
    # what went wrong in its one line, as every check-device does
    qtm_log = logging.getLogger('qtm_rt')
    propagate, qtm_log.propagate = qtm_log.propagate, False
    try:
        with device_endpoint(host, (host, port), QtmEmulator) as (host, port):
            return asyncio.run(_check(host, port or DEFAULT_PORT, target))
    finally:
        qtm_log.propagate = propagate


async def _check(host: str, port: int, target: CheckTarget) -> list[str]:
    where = tcp_address(host, port)
    conn = await open_session(host, port, VERSION, target.timeout)
    try:
        names = await read_bodies(conn, where)
        body = target.name or (names[0] if names else '')
        index = body_index(names, body, where)
        try:
            packet: Any = await conn.get_current_frame(components=['6d'])
        except asyncio.TimeoutError as err:
            raise DeviceError(f'{where}: no answer to GetCurrentFrame 6D (is QTM '
                              'measuring?)') from err
        except qtm_rt.QRTCommandException as err:
            raise DeviceError(f'{where}: GetCurrentFrame 6D refused: {qtm_said(err)}') from err
    finally:
        conn.disconnect()
    lines = [f'{where}: QTM RT protocol {VERSION}, 6D bodies: {", ".join(names)}']
    pose = pose_of(packet, index)
    if pose is None:
        return lines + [f'{where}: {body!r} not tracked in frame {packet.framenumber} (NaN)']
    p, r = pose
    yaw = math.degrees(math.atan2(r[1, 0], r[0, 0]))
    return lines + [f'{where}: {body!r} in frame {packet.framenumber}: x {p[0]:.1f} mm, '
                    f'y {p[1]:.1f} mm, z {p[2]:.1f} mm, yaw {yaw:.1f} deg (QTM frame)']
