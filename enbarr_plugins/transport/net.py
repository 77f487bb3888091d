"""TCP and UDP links to devices on the network (a motion-capture server, a networked sensor).

``TcpClient`` connects with a connect timeout, reads with a read timeout, and reconnects on
demand with a bounded number of attempts; ``UdpSocket`` sends and receives datagrams with a
receive timeout. Every failure (refused, reset, timed out, closed by the peer) is a
``DeviceError`` naming host and port, raised ``from`` the ``OSError``; no call blocks longer
than the timeout it was given (per attempt). Plain ``socket`` (Python standard library).
"""

from __future__ import annotations

import socket
import time

from enbarr_core.framework.errors import DeviceError


class TcpClient:
    """A TCP connection to ``host:port`` that can be re-established.

    ``connect()`` tries up to ``attempts`` times, ``retry_delay`` [s] apart, each attempt
    bounded by ``connect_timeout`` [s]; reads wait at most ``read_timeout`` [s]. After any
    failure the socket is closed (``connected`` is False) and the next ``connect()`` opens a
    fresh one; ``reconnects`` counts the connections made after the first.
    """

    def __init__(self, host: str, port: int, *, connect_timeout: float = 1.0,
                 read_timeout: float = 0.5, attempts: int = 1, retry_delay: float = 0.1) -> None:
        if not (connect_timeout > 0.0 and read_timeout > 0.0):
            raise ValueError(f'connect_timeout/read_timeout: must be > 0 s, got '
                             f'{connect_timeout}, {read_timeout}')
        if attempts < 1 or retry_delay < 0.0:
            raise ValueError(f'attempts/retry_delay: must be >= 1 and >= 0 s, got {attempts}, '
                             f'{retry_delay}')
        self.host = host
        self.port = port
        self.connect_timeout = connect_timeout
        self.read_timeout = read_timeout
        self.attempts = attempts
        self.retry_delay = retry_delay
        self.connections = 0
        self._sock: socket.socket | None = None
        self._buf = bytearray()

    @property
    def name(self) -> str:
        """``tcp://host:port``, as messages show it."""
        return f'tcp://{self.host}:{self.port}'

    @property
    def connected(self) -> bool:
        """Whether a connection is open."""
        return self._sock is not None

    @property
    def reconnects(self) -> int:
        """Connections made after the first."""
        return max(0, self.connections - 1)

    def connect(self) -> None:
        """Open the connection (a no-op when open); ``DeviceError`` after the last attempt."""
        if self._sock is not None:
            return
        for attempt in range(self.attempts):
            try:
                sock = socket.create_connection((self.host, self.port),
                                                timeout=self.connect_timeout)
            except OSError as err:
                if attempt + 1 == self.attempts:
                    raise DeviceError(f'{self.name}: cannot connect ({self.attempts} '
                                      f'attempts): {err}') from err
                time.sleep(self.retry_delay)
                continue
            sock.settimeout(self.read_timeout)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._sock = sock
            self._buf.clear()
            self.connections += 1
            return

    def _fail(self, what: str, err: BaseException | None = None) -> DeviceError:
        self.close()
        detail = f': {err}' if err is not None else ''
        return DeviceError(f'{self.name}: {what}{detail}')

    def send(self, data: bytes) -> None:
        """Send all of ``data``."""
        sock = self._require()
        try:
            sock.sendall(data)
        except OSError as err:  # includes socket.timeout
            raise self._fail('send failed', err) from err

    def _recv(self) -> bytes:
        sock = self._require()
        try:
            data = sock.recv(65536)
        except socket.timeout as err:
            raise DeviceError(f'{self.name}: no data for {self.read_timeout} s') from err
        except OSError as err:
            raise self._fail('receive failed', err) from err
        if not data:
            raise self._fail('connection closed by the peer')
        return data

    def read_some(self) -> bytes:
        """Return what has arrived (at least one byte); wait at most ``read_timeout``."""
        if self._buf:
            data, self._buf = bytes(self._buf), bytearray()
            return data
        return self._recv()

    def read_exactly(self, n: int) -> bytes:
        """Exactly ``n`` bytes; each wait for more is bounded by ``read_timeout``.

        A timeout keeps the bytes already received for the next read (the connection
        stays open); the peer closing it is a fault.
        """
        while len(self._buf) < n:
            self._buf += self._recv()
        data, self._buf = bytes(self._buf[:n]), self._buf[n:]
        return data

    def read_line(self, delimiter: bytes = b'\n', max_length: int = 65536) -> bytes:
        """Read up to and including ``delimiter``; a longer line than ``max_length`` is a fault."""
        while True:
            end = self._buf.find(delimiter)
            if end >= 0:
                end += len(delimiter)
                data, self._buf = bytes(self._buf[:end]), self._buf[end:]
                return data
            if len(self._buf) > max_length:
                raise self._fail(f'no {delimiter!r} in {max_length} bytes')
            self._buf += self._recv()

    def _require(self) -> socket.socket:
        if self._sock is None:
            raise DeviceError(f'{self.name}: not connected')
        return self._sock

    def close(self) -> None:
        """Close the connection (a no-op when closed); never raises."""
        sock, self._sock = self._sock, None
        self._buf.clear()
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass


class UdpSocket:
    """A UDP socket bound to ``bind_host:bind_port`` (port 0: any free one).

    ``recv()`` waits at most ``timeout`` [s] and returns None when nothing came; ``send_to``
    sends one datagram. Failures are ``DeviceError``s naming the local address.
    """

    def __init__(self, bind_host: str = '127.0.0.1', bind_port: int = 0, *,
                 timeout: float = 0.1, max_size: int = 65535) -> None:
        if not timeout > 0.0:
            raise ValueError(f'timeout: must be > 0 s, got {timeout}')
        self.max_size = max_size
        self.timeout = timeout
        self.received = 0
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((bind_host, bind_port))
        except OSError as err:
            self._sock.close()
            raise DeviceError(f'udp://{bind_host}:{bind_port}: cannot bind: {err}') from err
        self._sock.settimeout(timeout)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]

    @property
    def name(self) -> str:
        """``udp://host:port`` of the local end."""
        return f'udp://{self.address[0]}:{self.address[1]}'

    def recv(self) -> tuple[bytes, tuple[str, int]] | None:
        """One datagram and its sender, or None after ``timeout``."""
        try:
            data, sender = self._sock.recvfrom(self.max_size)
        except socket.timeout:
            return None
        except OSError as err:
            raise DeviceError(f'{self.name}: receive failed: {err}') from err
        self.received += 1
        return data, sender[:2]

    def send_to(self, data: bytes, address: tuple[str, int]) -> None:
        """Send ``data`` as one datagram to ``address``."""
        try:
            self._sock.sendto(data, address)
        except OSError as err:
            raise DeviceError(f'{self.name}: send to {address[0]}:{address[1]} failed: '
                              f'{err}') from err

    def close(self) -> None:
        """Close the socket; never raises."""
        try:
            self._sock.close()
        except OSError:
            pass
