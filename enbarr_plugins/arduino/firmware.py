"""The Arduino PWM board's firmware logic, compiled for the host and loaded with ctypes.

The board's protocol and watchdog are portable C (``firmware/enbarr_arduino/link.c`` and
``link.h``; the protocol is documented there and in ``docs/hardware.md``). The emulator
runs that very code: ``load()`` compiles it with the host's C compiler
(``cc -shared -fPIC -O2``) into a cache directory keyed by the sources' hash
(``$XDG_CACHE_HOME/enbarr/firmware`` or ``~/.cache/enbarr/firmware``; ``ENBARR_CACHE``
overrides it) and ``Board`` is one board instance over it. With no C compiler the error says
what to install. ``defines()`` reads the numbers of ``link.h`` (message types, flags, channel
count): the emulator takes its protocol constants from the firmware's own header, not from the
driver's ``arduino/protocol.py``, so a wrong number on the driver's side is not copied into
the board it is tested against. The sources are found beside the package (a source checkout)
or in the package's share directory (``share/enbarr/firmware``, installed by ``setup.py``).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys
import tempfile
import threading

from enbarr_core.framework.errors import DeviceError

SOURCES = ('link.c', 'link.h')
LIBRARY = 'libenbarr_link.so'

# Counter ids of link.h (enum enb_counter_id), in order.
COUNTERS = ('frames', 'crc_errors', 'seq_errors', 'refused', 'truncated', 'watchdog_trips',
            'tx_dropped', 'bytes_in')


class FirmwareBuildError(DeviceError):
    """The firmware could not be found or compiled for the host."""


def source_dir() -> Path:
    """Return the directory holding ``link.c`` and ``link.h``."""
    here = Path(__file__).resolve()
    candidates = [here.parents[2] / 'firmware' / 'enbarr_arduino',
                  Path(sys.prefix) / 'share' / 'enbarr' / 'firmware' / 'enbarr_arduino']
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory('enbarr')) / 'firmware'
                          / 'enbarr_arduino')
    except Exception:  # noqa: BLE001 - not in a ROS workspace, or the package not installed
        pass
    for c in candidates:
        if all((c / s).is_file() for s in SOURCES):
            return c
    raise FirmwareBuildError('firmware sources (link.c, link.h) not found in: '
                             + ', '.join(str(c) for c in candidates))


def cache_dir() -> Path:
    """Return the directory the host builds are cached in."""
    base = os.environ.get('ENBARR_CACHE')
    if base:
        return Path(base) / 'firmware'
    xdg = os.environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(xdg) / 'enbarr' / 'firmware'


def compiler() -> str:
    """Return the host C compiler (``$CC``, cc, gcc or clang); FirmwareBuildError if none."""
    for name in (os.environ.get('CC'), 'cc', 'gcc', 'clang'):
        if name and shutil.which(name):
            return name
    raise FirmwareBuildError(
        'no C compiler found (tried $CC, cc, gcc, clang): the Arduino emulator compiles the '
        'board firmware for this computer; install one (Debian/Ubuntu: '
        'apt-get install -y --no-install-recommends gcc libc6-dev)')


def build(src: Path | None = None) -> Path:
    """Compile the firmware for the host unless a build of these sources is cached; its path."""
    src = src or source_dir()
    digest = hashlib.sha256()
    for name in SOURCES:
        digest.update(name.encode() + b'\0' + (src / name).read_bytes())
    out = cache_dir() / digest.hexdigest()[:16] / LIBRARY
    if out.is_file():
        return out
    cc = compiler()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(suffix='.so', dir=out.parent)
    except OSError as err:
        raise FirmwareBuildError(f'{out.parent}: cannot write the firmware build there '
                                 f'({err.strerror}); set ENBARR_CACHE to a writable '
                                 'directory') from err
    os.close(fd)
    cmd = [cc, '-shared', '-fPIC', '-O2', '-std=c99', '-Wall', '-Wextra', '-o', tmp,
           str(src / 'link.c')]
    try:
        result = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        if result.returncode != 0:
            raise FirmwareBuildError(f'{" ".join(cmd)} failed:\n{result.stderr.strip()}')
        os.replace(tmp, out)  # atomic: a parallel build wins or loses whole
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out


@functools.cache
def defines() -> dict[str, int]:
    """Return the numeric ``#define ENB_NAME value`` lines of ``link.h`` by name."""
    text = (source_dir() / 'link.h').read_text()
    return {m[1]: int(m[2], 0) for m in re.finditer(
        r'^#define (ENB_\w+)\s+(0x[0-9A-Fa-f]+|[0-9]+)u?\b', text, re.M)}


_lock = threading.Lock()
_lib: ctypes.CDLL | None = None


def load() -> ctypes.CDLL:
    """Return the host build of the firmware as a ctypes library (built on first use)."""
    global _lib
    with _lock:
        if _lib is None:
            lib = ctypes.CDLL(str(build()))
            u8, u16, u32, p = ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32, ctypes.c_void_p
            buf = ctypes.c_char_p
            for name, res, args in (
                    ('enb_crc16', u16, [buf, u16, u16]),
                    ('enb_init', None, [p, u32, u16, u8]),
                    ('enb_rx', None, [p, buf, u16, u32]),
                    ('enb_tick', None, [p, u32]),
                    ('enb_tx', u16, [p, p, u16]),
                    ('enb_duty', u16, [p, u8]),
                    ('enb_flags', u8, [p]),
                    ('enb_counter', u16, [p, u8]),
                    ('enb_link_size', ctypes.c_size_t, [])):
                f = getattr(lib, name)
                f.restype, f.argtypes = res, args
            _lib = lib
        return _lib


class Board:
    """One instance of the board's firmware logic (an ``enb_link``); not thread safe.

    ``now_ms`` arguments are the board's ``millis()``: any millisecond counter (taken mod
    2**32 like the board's).
    """

    def __init__(self, now_ms: int, boot_count: int = 1, reset_cause: int = 1) -> None:
        self.lib = load()
        self._state = ctypes.create_string_buffer(self.lib.enb_link_size())
        self._out = ctypes.create_string_buffer(256)
        self.channels = defines()['ENB_CHANNELS']
        self.reset(now_ms, boot_count, reset_cause)

    def reset(self, now_ms: int, boot_count: int = 1, reset_cause: int = 1) -> None:
        """Power-on reset: defaults, outputs neutral, HELLO queued."""
        self.lib.enb_init(self._state, now_ms & 0xFFFFFFFF, boot_count & 0xFFFF,
                          reset_cause & 0xFF)

    def rx(self, data: bytes, now_ms: int) -> None:
        """Feed received bytes."""
        for i in range(0, len(data), 0xFFFF):
            chunk = data[i:i + 0xFFFF]
            self.lib.enb_rx(self._state, chunk, len(chunk), now_ms & 0xFFFFFFFF)

    def tick(self, now_ms: int) -> None:
        """Run the watchdog and the partial-frame timeout."""
        self.lib.enb_tick(self._state, now_ms & 0xFFFFFFFF)

    def tx(self) -> bytes:
        """Take every byte the board has queued for sending."""
        out = bytearray()
        while True:
            n = self.lib.enb_tx(self._state, self._out, len(self._out))
            if not n:
                return bytes(out)
            out += self._out.raw[:n]

    def duties(self) -> list[int]:
        """Output duty of each channel [0.01 %]."""
        return [self.lib.enb_duty(self._state, ch) for ch in range(self.channels)]

    @property
    def flags(self) -> int:
        """STATUS flags (link.h ENB_FLAG_*)."""
        return self.lib.enb_flags(self._state)

    def counters(self) -> dict[str, int]:
        """Return the board's counters by name (``COUNTERS``)."""
        return {name: self.lib.enb_counter(self._state, i) for i, name in enumerate(COUNTERS)}


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE computed by the firmware's own code."""
    return load().enb_crc16(data, len(data), crc)
