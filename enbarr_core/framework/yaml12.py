"""The YAML loader of profiles, scenarios, ``--set`` values and script values: YAML 1.2 scalars.

PyYAML implements YAML 1.1, where a float needs a dot: ``1e9`` is the string ``'1e9'``,
``012`` is octal 10, ``1_000`` is 1000, ``1:20`` is the sexagesimal 80, and ``on``, ``off``,
``yes`` and ``no`` are booleans. YAML 1.2 (its core schema) reads ``1e9`` as a float, ``012``
as 12, and the others as strings. A profile author who writes ``max_gap: 1e9`` means a
number, and one who writes ``ROS_AUTOMATIC_DISCOVERY_RANGE: OFF`` means the word OFF, so
every YAML a user writes for Enbarr goes through ``Yaml12Loader``: PyYAML's safe loader
(libyaml's parser when available) resolving plain ints, floats and booleans as the YAML 1.2
core schema does (section 10.3.2). Null and the rest stay as PyYAML reads them.

Pure: no rclpy.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

#: libyaml when PyYAML has it: the pure-Python scanner is many times slower on a large file.
#: Both parse the same documents; only the resolution of plain scalars is changed below.
_Base: Any = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)

BOOL_TAG = 'tag:yaml.org,2002:bool'
INT_TAG = 'tag:yaml.org,2002:int'
FLOAT_TAG = 'tag:yaml.org,2002:float'

#: The longest integer read [digits]: ROS integers have 19 at most.
MAX_INT_DIGITS = 100
#: YAML 1.2 core schema, section 10.3.2: the only booleans.
BOOL_12 = re.compile(r'^(?:true|True|TRUE|false|False|FALSE)$')

#: YAML 1.2 core schema, section 10.3.2: int is decimal, 0o octal or 0x hexadecimal.
INT_12 = re.compile(r'^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$')
#: ... and float: a dot or an exponent (``1e9``), or infinity / not-a-number. A plain integer
#: also fits the core schema's float pattern; it resolves as int first (1.2, table 10.3.2),
#: so here the float pattern leaves it out.
FLOAT_12 = re.compile(r"""^(?:
    [-+]?(?:[0-9]+\.[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?
  | [-+]?[0-9]+[eE][-+]?[0-9]+
  | [-+]?\.(?:inf|Inf|INF)
  | \.(?:nan|NaN|NAN)
)$""", re.VERBOSE)


class Yaml12Loader(_Base):  # type: ignore[misc]  # PyYAML has no stubs here: its loader is Any
    """PyYAML's safe loader resolving plain ints, floats and booleans as YAML 1.2 (core)."""

    def construct_yaml_int(self, node: Any) -> int:
        """Construct a 1.2 int: decimal (leading zeros are decimal), ``0o`` octal, ``0x`` hex.

        More than ``MAX_INT_DIGITS`` digits is a YAML error at the value's line: Python
        refuses to convert past 4300 digits, and nothing a profile holds needs a twentieth.
        """
        text = self.construct_scalar(node)
        if len(text) > MAX_INT_DIGITS:
            raise yaml.constructor.ConstructorError(
                None, None, f'an integer of {len(text)} digits (at most {MAX_INT_DIGITS})',
                node.start_mark)
        if text.startswith('0o'):
            return int(text[2:], 8)
        if text.startswith('0x'):
            return int(text[2:], 16)
        return int(text, 10)

    def construct_yaml_float(self, node: Any) -> float:
        """Construct a 1.2 float (``.inf``, ``-.Inf``, ``.nan`` included)."""
        text = self.construct_scalar(node)
        lowered = text.lower()
        if lowered.endswith('.inf'):
            return float('-inf') if lowered.startswith('-') else float('inf')
        if lowered == '.nan':
            return float('nan')
        return float(text)


# Copy the inherited table before editing it (PyYAML shares one dict along a class hierarchy
# until a subclass adds its own), then drop the 1.1 bool, int and float resolvers.
Yaml12Loader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers
            if tag not in (BOOL_TAG, INT_TAG, FLOAT_TAG)]
    for first, resolvers in _Base.yaml_implicit_resolvers.items()}
Yaml12Loader.add_implicit_resolver(BOOL_TAG, BOOL_12, list('tTfF'))
Yaml12Loader.add_implicit_resolver(INT_TAG, INT_12, list('-+0123456789'))
Yaml12Loader.add_implicit_resolver(FLOAT_TAG, FLOAT_12, list('-+0123456789.'))
Yaml12Loader.add_constructor(INT_TAG, Yaml12Loader.construct_yaml_int)
Yaml12Loader.add_constructor(FLOAT_TAG, Yaml12Loader.construct_yaml_float)


def load(text: str) -> Any:
    """Parse one YAML document with ``Yaml12Loader`` (``yaml.safe_load`` with 1.2 numbers)."""
    return yaml.load(text, Loader=Yaml12Loader)  # noqa: S506 - a SafeLoader subclass
