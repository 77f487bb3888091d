"""TCP client and UDP socket against loopback servers started by the test."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins.transport.net import TcpClient, UdpSocket


class Server:
    """A loopback TCP server: accepts connections, sends ``greeting``, echoes, can drop."""

    def __init__(self, greeting: bytes = b'') -> None:
        self.sock = socket.socket()
        self.sock.bind(('127.0.0.1', 0))
        self.sock.listen()
        self.port = self.sock.getsockname()[1]
        self.greeting = greeting
        self.conns: list[socket.socket] = []
        self.accepted = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            if self.greeting:
                conn.sendall(self.greeting)
            self.accepted.set()

    def drop(self) -> None:
        for conn in self.conns:
            conn.close()
        self.conns.clear()
        self.accepted.clear()

    def close(self) -> None:
        self.drop()
        self.sock.close()


@pytest.fixture
def server():
    s = Server(b'hello\nworld\n')
    yield s
    s.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def test_lines_and_exact_reads(server):
    client = TcpClient('127.0.0.1', server.port, read_timeout=2.0)
    client.connect()
    assert client.read_line() == b'hello\n'
    assert client.read_exactly(3) == b'wor'
    assert client.read_some() == b'ld\n'
    client.close()


def test_send_reaches_the_server(server):
    client = TcpClient('127.0.0.1', server.port, read_timeout=2.0)
    client.connect()
    assert server.accepted.wait(5.0)
    client.send(b'ping')
    assert server.conns[0].recv(4) == b'ping'
    client.close()


def test_a_read_timeout_is_bounded_and_keeps_the_connection(server):
    client = TcpClient('127.0.0.1', server.port, read_timeout=0.05)
    client.connect()
    client.read_line()
    client.read_line()
    start = time.monotonic()
    with pytest.raises(DeviceError, match=rf'tcp://127.0.0.1:{server.port}: no data for 0.05'):
        client.read_some()
    assert time.monotonic() - start < 1.0
    assert client.connected
    client.close()


def test_refused_connection_names_host_and_port():
    port = free_port()
    client = TcpClient('127.0.0.1', port, connect_timeout=0.5, attempts=2, retry_delay=0.0)
    with pytest.raises(DeviceError, match=rf'tcp://127.0.0.1:{port}: cannot connect '
                       r'\(2 attempts\)') as info:
        client.connect()
    assert isinstance(info.value.__cause__, OSError)
    assert not client.connected


def test_peer_closing_is_a_fault_and_reconnect_works(server):
    client = TcpClient('127.0.0.1', server.port, read_timeout=2.0)
    client.connect()
    assert client.read_line() == b'hello\n'
    assert server.accepted.wait(5.0)
    server.drop()
    with pytest.raises(DeviceError, match='closed by the peer|receive failed'):
        while True:
            client.read_some()
    assert not client.connected
    client.connect()
    assert client.read_line() == b'hello\n'
    assert client.connections == 2 and client.reconnects == 1
    client.close()


def test_send_without_connection_is_a_device_error():
    client = TcpClient('127.0.0.1', free_port())
    with pytest.raises(DeviceError, match='not connected'):
        client.send(b'x')


def test_bad_timeouts_name_the_field():
    with pytest.raises(ValueError, match='connect_timeout'):
        TcpClient('127.0.0.1', 1, connect_timeout=0.0)
    with pytest.raises(ValueError, match='attempts'):
        TcpClient('127.0.0.1', 1, attempts=0)


def test_udp_round_trip_and_bounded_receive():
    a, b = UdpSocket(timeout=0.05), UdpSocket(timeout=2.0)
    try:
        start = time.monotonic()
        assert a.recv() is None
        assert time.monotonic() - start < 1.0
        a.send_to(b'pose', b.address)
        data, sender = b.recv()
        assert data == b'pose' and sender == a.address and b.received == 1
    finally:
        a.close()
        b.close()


def test_udp_bind_failure_names_the_address():
    a = UdpSocket()
    try:
        with pytest.raises(DeviceError, match=f'udp://127.0.0.1:{a.address[1]}: cannot bind'):
            UdpSocket(bind_port=a.address[1])
    finally:
        a.close()
