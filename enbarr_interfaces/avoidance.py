"""What the collision avoidance did for one estimate, as ``guidance/avoidance`` carries it.

``control/avoidance`` (the force-level filter's, in the DP controller) has the same encoding.

A ``std_msgs/Float64MultiArray`` (no custom message can be built in a pip install): one
dimension, ``layout.dim[0].label`` = the field names of :data:`FIELDS` joined by commas (so
a reader can check the order), size = stride = their number, ``data`` the values in that
order. Stamps are split into seconds and nanoseconds (each exact in a float64), so a reader
can match the obstacle message used and compute the latency scan stamp -> safe reference.
``docs/interfaces.md`` ("Collision avoidance") documents the fields.
"""

from __future__ import annotations

from collections.abc import Mapping

from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from enbarr_interfaces.convert import NS_PER_S
from enbarr_interfaces.fastmsg import new

#: (name, meaning) of each value, in wire order.
FIELDS: tuple[tuple[str, str], ...] = (
    ('estimate_stamp_sec', 'stamp of the estimate the reference answers (guidance/reference)'),
    ('estimate_stamp_nanosec', ''),
    ('obstacles_stamp_sec', 'header stamp of the obstacles message used (0: none)'),
    ('obstacles_stamp_nanosec', ''),
    ('solve_time', 'wall time of the safety filter step [s]'),
    ('active', 'obstacle constraints binding at the safe velocity'),
    ('infeasible', '1: no velocity met every constraint, stopped'),
    ('min_barrier', 'min_i B_i at the desired position [m] (inf: no obstacle)'),
    ('engaged', '1: the reference differs from the guidance law'),
    ('blind', '1: obstacles stale or pose lost, holding'),
    ('obstacles', 'number of obstacles considered'),
)
NAMES = tuple(name for name, _ in FIELDS)
LABEL = ','.join(NAMES)
#: The layout of every message, built once (one per control step: the constructors' checks
#: cost more than the data). Shared by the messages: a receiver must not change it.
_DIM = MultiArrayDimension(label=LABEL, size=len(NAMES), stride=len(NAMES))


def to_msg(values: Mapping[str, float], estimate_ns: int, obstacles_ns: int | None
           ) -> Float64MultiArray:
    """Encode ``values`` (every name of :data:`FIELDS` but the stamps) and the two stamps."""
    stamps = {}
    for prefix, ns in (('estimate', estimate_ns), ('obstacles', obstacles_ns or 0)):
        stamps[f'{prefix}_stamp_sec'], stamps[f'{prefix}_stamp_nanosec'] = divmod(ns, NS_PER_S)
    merged = {**values, **stamps}
    msg = new(Float64MultiArray)
    msg.layout.dim = [_DIM]
    msg.data = [float(merged[name]) for name in NAMES]
    return msg


def from_msg(msg: Float64MultiArray) -> dict[str, float]:
    """Decode a ``guidance/avoidance`` message by the names its layout gives.

    The two stamps are also given whole, as ``estimate_stamp_ns`` and ``obstacles_stamp_ns``.
    ValueError when the layout is not one dimension labelled with field names that the data
    fills.
    """
    dims = list(msg.layout.dim)
    if len(dims) != 1:
        raise ValueError(f'guidance/avoidance: expected one dimension, got {len(dims)}')
    names = dims[0].label.split(',')
    data = list(msg.data)
    if len(names) != len(data) or dims[0].size != len(data):
        raise ValueError(f'guidance/avoidance: {len(names)} labels for {len(data)} values')
    out = dict(zip(names, data))
    for prefix in ('estimate', 'obstacles'):
        out[f'{prefix}_stamp_ns'] = int(out[f'{prefix}_stamp_sec']) * NS_PER_S \
            + int(out[f'{prefix}_stamp_nanosec'])
    return out
