"""ROS 2 parameters as the Foxglove WebSocket protocol names and types them, both ways.

A parameter of node ``/ns/node`` is ``/ns/node.name`` to a Foxglove client (the
``parametersPanel`` shows one flat list; the node's fully qualified name keeps nodes of the
same name in different namespaces apart, and the dot cannot occur in a node name).

ROS types are kept: a double goes out with the protocol's ``float64`` hint (``1.0`` would
read back as an integer otherwise), and a value coming in is coerced to the type the
parameter already has where the wire cannot tell them apart (an integer for a double, a
list of integers for a double array, base64 text for a byte array). Anything else is left as
the client sent it, so that rclpy's own type check refuses it with its reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import foxglove
from foxglove import ParameterType as FoxType
from rclpy.parameter import Parameter

RosType = Parameter.Type


@dataclass(frozen=True)
class ParamName:
    """A Foxglove parameter name split into its node and the node's parameter."""

    node: str   # fully qualified node name, ``/ns/node``
    name: str   # the parameter's name in that node


def foxglove_name(node: str, name: str) -> str:
    """Return the Foxglove name of parameter ``name`` of the node ``node`` (fully qualified)."""
    return f'{node}.{name}'


def split_name(full: str) -> ParamName | None:
    """Split ``/ns/node.name``; None when it names no node (no leading slash or no dot)."""
    node, dot, name = full.partition('.')
    if not full.startswith('/') or not dot or not name or node == '/':
        return None
    return ParamName(node, name)


def to_foxglove(full_name: str, param: Parameter) -> foxglove.Parameter:
    """Return ROS parameter ``param`` as a Foxglove parameter named ``full_name``."""
    kind = param.type_
    value = param.value
    if kind == RosType.NOT_SET:
        return foxglove.Parameter(full_name)
    if kind == RosType.DOUBLE:
        return foxglove.Parameter(full_name, value=float(value), type=FoxType.Float64)
    if kind == RosType.DOUBLE_ARRAY:
        return foxglove.Parameter(full_name, value=[float(v) for v in value],
                                  type=FoxType.Float64Array)
    if kind == RosType.BYTE_ARRAY:
        return foxglove.Parameter(full_name, value=b''.join(value))
    if kind in (RosType.BOOL_ARRAY, RosType.INTEGER_ARRAY, RosType.STRING_ARRAY):
        return foxglove.Parameter(full_name, value=list(value))
    return foxglove.Parameter(full_name, value=value)


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def to_ros(name: str, value: Any, current: RosType) -> Parameter:
    """Return the ROS parameter ``name`` = ``value`` (a client's native value).

    ``current`` is the type the parameter has now: a number or list the wire cannot type
    precisely takes it. A value that still does not fit is returned as sent; rclpy's set
    refuses it, with its reason.
    """
    if current == RosType.DOUBLE and _is_int(value):
        value = float(value)
    elif current == RosType.DOUBLE_ARRAY and isinstance(value, list) \
            and all(_is_int(v) or isinstance(v, float) for v in value):
        value = [float(v) for v in value]
    elif current == RosType.BYTE_ARRAY and isinstance(value, (bytes, bytearray)):
        value = [bytes([b]) for b in value]
    elif isinstance(value, list) and not value:
        # An empty list has no element type on the wire: the parameter's own type.
        return Parameter(name, current, [])
    if value is None:
        return Parameter(name, RosType.NOT_SET, None)
    return Parameter(name, value=value)
