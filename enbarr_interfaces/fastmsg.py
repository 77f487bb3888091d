"""Build ROS messages without their generated ``__init__``: ``new(Imu)`` equals ``Imu()``.

Why: rosidl's generated constructors import their field types, parse keyword arguments and
go through every property setter at each call (``docs/benchmarks.md``), and the ROV chain
builds about ten messages per sample at 400 Hz.
``new(cls)`` makes the same object from a builder compiled once per type: a plain
``cls.__new__`` with every slot assigned directly from the defaults of one ``cls()``
(nested messages built by their own builders, numpy arrays and ``array.array`` sequences
copied, immutable values shared), so each message is independent and equal to ``cls()``,
field by field and serialized byte for byte (``test/interfaces/test_fastmsg.py`` checks every
type of the topic contract).

Use it where a node builds a message per sample; anywhere else ``cls()`` reads better. Set
fields as usual afterwards (the setters still check what they are given when
``ROS_PYTHON_CHECK_FIELDS=1``).
"""

from __future__ import annotations

import array
from collections.abc import Callable
import threading
from typing import Any, TypeVar

import numpy as np

M = TypeVar('M')

_builders: dict[type, Callable[[], Any]] = {}
_lock = threading.Lock()


def new(cls: type[M]) -> M:
    """Return a new ``cls`` message with its default field values, as ``cls()`` does."""
    build: Callable[[], M] | None = _builders.get(cls)
    if build is None:
        build = builder(cls)
    return build()


def is_message(value: Any) -> bool:
    """Whether ``value`` is a rosidl-generated message (or its class)."""
    cls = value if isinstance(value, type) else type(value)
    return hasattr(cls, 'get_fields_and_field_types') and hasattr(cls, '__slots__')


def builder(cls: type[M]) -> Callable[[], M]:
    """Return (compiling once) the function that builds a default ``cls``."""
    with _lock:
        build = _builders.get(cls)
        if build is not None:
            return build
    if not is_message(cls):
        raise TypeError(f'{cls!r} is not a ROS message class')
    proto = cls()
    env: dict[str, Any] = {'cls': cls, 'np': np, 'array': array.array}
    lines = ['def build():', '    m = cls.__new__(cls)']
    for i, slot in enumerate(getattr(cls, '__slots__')):  # M is any message class
        value = object.__getattribute__(proto, slot)
        name = f'v{i}'
        env[name] = value
        if is_message(value):
            env[name] = builder(type(value))
            lines.append(f'    m.{slot} = {name}()')
        elif isinstance(value, np.ndarray):
            lines.append(f'    m.{slot} = {name}.copy()')
        elif isinstance(value, array.array):
            env[f't{i}'] = value.typecode
            lines.append(f'    m.{slot} = array(t{i}, {name})')
        elif isinstance(value, list):
            if any(is_message(v) for v in value):
                env[name] = [builder(type(v)) for v in value]
                lines.append(f'    m.{slot} = [b() for b in {name}]')
            else:
                lines.append(f'    m.{slot} = list({name})')
        elif isinstance(value, (bool, int, float, str, bytes, type(None))):
            lines.append(f'    m.{slot} = {name}')
        else:
            raise TypeError(f'{cls.__name__}.{slot}: no fast copy for a {type(value).__name__}')
    lines.append('    return m')
    exec(compile('\n'.join(lines), f'<fastmsg {cls.__module__}.{cls.__name__}>', 'exec'), env)  # noqa: S102 - code built here from slot names
    build = env['build']
    with _lock:
        return _builders.setdefault(cls, build)
