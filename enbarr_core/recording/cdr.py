"""Per-type CDR encoders for rclpy messages, generated once from the message definition.

rclpy's ``serialize_message`` converts the Python message to its C struct field by field and
then serializes it, which costs more than the rest of recording (``docs/benchmarks.md``).
``encoder(cls)`` instead compiles, once per message class, a Python function that reads the
fields and packs them with ``struct`` (numeric arrays and sequences with ``tobytes``), merging
every run of fixed-size fields whose alignment is known at generation time into one ``pack``
call. The output is the little-endian CDR (XCDR1) that rmw_fastrtps writes: the 4-byte
encapsulation header ``00 01 00 00``, every primitive aligned to its size (at most 8) counted
from the end of that header, strings as a uint32 length that counts the terminating NUL,
sequences as a uint32 count. ``test/recording/test_cdr.py`` checks it against
``serialize_message`` byte for byte. Unlike ``serialize_message``, whose buffer is the
*estimated* size for messages with string sequences, the result ends exactly where the CDR does.

A type with a field kind this does not cover (``char``, wide strings) gets ``None``:
the caller falls back to ``serialize_message``. A big-endian host gets ``None`` for every
type (the ``tobytes`` paths are native-endian).
"""

from __future__ import annotations

from collections.abc import Callable
import importlib
import struct
import sys
from typing import Any

import rosidl_parser.definition as idl

Encoder = Callable[[Any], bytes]

#: CDR little-endian encapsulation header (representation id CDR_LE, options 0).
HEADER = b'\x00\x01\x00\x00'

# IDL basic type -> (struct code, size); rclpy holds a ``byte`` (octet) as bytes of length 1.
# char/wchar are left out: such types fall back.
_BASIC = {
    'boolean': ('?', 1), 'int8': ('b', 1), 'uint8': ('B', 1), 'int16': ('h', 2),
    'uint16': ('H', 2), 'int32': ('i', 4), 'uint32': ('I', 4), 'int64': ('q', 8),
    'uint64': ('Q', 8), 'float': ('f', 4), 'double': ('d', 8), 'octet': ('c', 1),
}


class Unsupported(Exception):
    """The message type has a field kind the generator does not cover."""


def _message_class(t: idl.NamespacedType) -> type:
    return getattr(importlib.import_module('.'.join(t.namespaces)), t.name)


class _Gen:
    """Emits the body of one encoder; tracks what is known of the offset mod 8."""

    def __init__(self, indent: str, known: bool, marked: bool = False) -> None:
        self.lines: list[str] = []
        self.marked = marked  # padding as pack arguments (from _Z), so a test can mark it
        self.indent = indent
        self.fmt = ''
        self.args: list[str] = []
        # The offset is ``val`` modulo ``mod`` (mod 1: nothing known).
        self.val, self.mod = (0, 8) if known else (0, 1)
        self.n = 0

    def var(self) -> str:
        self.n += 1
        return f'v{len(self.indent)}_{self.n}'

    def emit(self, line: str) -> None:
        self.flush()
        self.lines.append(self.indent + line)

    def flush(self) -> None:
        if self.fmt:
            self.lines.append(f"{self.indent}b += _pack('<{self.fmt}', {', '.join(self.args)})")
            self.fmt, self.args = '', []

    def align(self, a: int) -> None:
        if a <= self.mod:
            pad = (-self.val) % a
            if pad and self.marked:
                self.fmt += f'{pad}s'
                self.args.append(f'_Z[{pad}]')
            elif pad:
                self.fmt += f'{pad}x'
                self.val = (self.val + pad) % self.mod
        else:
            self.emit(f'b += _Z[(4 - len(b)) % {a}]')
            self.val, self.mod = 0, a

    def advance(self, n: int) -> None:
        self.val = (self.val + n) % self.mod

    def prim(self, typename: str, expr: str) -> None:
        code, size = _BASIC[typename]
        self.align(size)
        self.fmt += code
        self.args.append(expr)
        self.advance(size)

    def unknown(self, mod: int = 1) -> None:
        self.val, self.mod = 0, mod

    def string(self, expr: str) -> None:
        v = self.var()
        self.emit(f'{v} = {expr}.encode()')
        self.align(4)
        self.fmt += 'I'
        self.args.append(f'len({v}) + 1')
        self.emit(f"b += {v}; b += b'\\x00'")
        self.unknown()


def _member(g: _Gen, t: Any, expr: str, funcs: dict[str, str], out: list[str]) -> None:
    """Emit the encoding of one value of type ``t`` held in ``expr``."""
    if isinstance(t, idl.BasicType):
        if t.typename not in _BASIC:
            raise Unsupported(t.typename)
        g.prim(t.typename, expr)
    elif isinstance(t, (idl.UnboundedString, idl.BoundedString)):
        g.string(expr)
    elif isinstance(t, idl.NamespacedType):
        v = g.var()
        g.emit(f'{v} = {expr}')
        _struct(g, _message_class(t), v, funcs, out)
    elif isinstance(t, idl.Array):
        _array(g, t.value_type, expr, t.size, funcs, out)
    elif isinstance(t, idl.AbstractSequence):
        v = g.var()
        g.emit(f'{v} = {expr}')
        g.align(4)
        g.fmt += 'I'
        g.args.append(f'len({v})')
        g.advance(4)
        _array(g, t.value_type, v, None, funcs, out)
    else:
        raise Unsupported(type(t).__name__)


def _array(g: _Gen, vt: Any, expr: str, size: int | None, funcs: dict[str, str],
           out: list[str]) -> None:
    """Elements of a fixed array (``size``) or of a sequence (count already written)."""
    if isinstance(vt, idl.BasicType):
        if vt.typename not in _BASIC:
            raise Unsupported(vt.typename)
        code, width = _BASIC[vt.typename]
        if vt.typename == 'octet':
            g.emit(f"b += b''.join({expr})")
            g.unknown()
            return
        if vt.typename == 'boolean':
            g.emit(f"b += _pack('<%d?' % len({expr}), *{expr})")
            g.unknown()
            return
        if size is None:
            # An empty sequence is not padded (Fast CDR aligns only to write an element).
            if width > 1 and width > g.mod:
                g.emit(f'if len({expr}): b += _Z[(4 - len(b)) % {width}]')
            else:
                g.align(width)
            g.emit(f'b += {expr}.tobytes()')
            g.unknown(min(width, 4))  # after the count: 0 mod 4, then whole elements
            return
        g.align(width)
        g.emit(f'b += {expr}.tobytes()')
        g.advance(width * size)
        return
    v = g.var()
    g.emit(f'for {v} in {expr}:')
    inner = _Gen(g.indent + '    ', known=False, marked=g.marked)
    inner.n = g.n
    _member(inner, vt, v, funcs, out)
    inner.flush()
    g.lines.extend(inner.lines)
    g.n = inner.n
    g.unknown()


def _struct(g: _Gen, cls: type, expr: str, funcs: dict[str, str], out: list[str]) -> None:
    slots = getattr(cls, '__slots__', None)
    types = getattr(cls, 'SLOT_TYPES', None)
    if slots is None or types is None:
        raise Unsupported(cls.__name__)
    fields = [(s, t) for s, t in zip(slots, types) if s != '_check_fields']
    if not fields:
        raise Unsupported(f'{cls.__name__}: empty structure')
    for slot, t in fields:
        _member(g, t, f'{expr}.{slot}', funcs, out)


def _generate(cls: type, marked: bool = False) -> str:
    g = _Gen('    ', known=True, marked=marked)
    g.lines.append('    b = bytearray(_HEADER)')
    _struct(g, cls, 'm', {}, [])
    g.flush()
    return 'def encode(m):\n' + '\n'.join(g.lines) + '\n    return bytes(b)\n'


_CACHE: dict[type, Encoder | None] = {}


def _compile(cls: type, pad: int) -> Encoder | None:
    try:
        text = _generate(cls, marked=pad != 0)
    except Unsupported:
        return None
    scope: dict[str, Any] = {'_pack': struct.pack, '_HEADER': HEADER,
                             '_Z': tuple(bytes([pad]) * n for n in range(8))}
    exec(compile(text, f'<cdr encoder {cls.__module__}.{cls.__name__}>', 'exec'),  # noqa: S102
         scope)  # the source is generated above from the type's definition, no user input
    return scope['encode']


def encoder(cls: type) -> Encoder | None:
    """Return the CDR encoder of rclpy message class ``cls``, or None: fall back."""
    try:
        return _CACHE[cls]
    except KeyError:
        pass
    fn = _compile(cls, 0) if sys.byteorder == 'little' else None
    _CACHE[cls] = fn
    return fn


def padding_marking_encoder(cls: type, pad: int = 0xEE) -> Encoder | None:
    """Return an encoder that pads with ``pad`` instead of zeros (for tests).

    The positions where its output differs from ``encoder(cls)``'s are exactly the padding,
    whose content CDR leaves unspecified (rmw_fastrtps leaves whatever its buffer held).
    """
    return _compile(cls, pad)


def source(cls: type) -> str:
    """Return the generated encoder's source (for reading and debugging)."""
    return _generate(cls)
