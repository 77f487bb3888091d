"""Argument helpers shared by the ``enbarr`` subcommands.

Nothing in Enbarr imports back from here but the commands themselves: the checks of a time
span or a rate, and the hidden old spelling of an option that still works with a notice.
"""

from __future__ import annotations

import argparse
import math
import textwrap
from typing import Any

from enbarr_core.framework.checks import MAX_SECONDS
from enbarr_core.framework.errors import EnbarrError

#: The attribute of the parsed namespace that collects deprecation notices.
NOTICES = 'deprecated_notices'
#: The width ``wrap`` fills help paragraphs to (argparse's own default on a narrow terminal).
HELP_WIDTH = 79


def check_seconds(option: str, value: float | None, maximum: float = MAX_SECONDS) -> None:
    """Refuse a time span that is not a positive, finite number of seconds up to ``maximum``."""
    if value is None:
        return
    if not (value > 0 and math.isfinite(value)):
        raise EnbarrError(f'{option} must be a positive finite number of seconds, got {value}')
    if value > maximum:
        raise EnbarrError(f'{option} must be at most {maximum:.0f} s, got {value:g}')


def check_rate(option: str, value: float, maximum: float) -> None:
    """Refuse a rate that is not a positive, finite number of Hz up to ``maximum``."""
    if not (value > 0 and math.isfinite(value)):
        raise EnbarrError(f'{option} must be a positive finite number of Hz, got {value}')
    if value > maximum:
        raise EnbarrError(f'{option} must be at most {maximum:g} Hz, got {value:g}')


class DeprecatedAlias(argparse.Action):
    """An old spelling of an argument: hidden from ``--help``, stored where it says.

    Using it adds a notice (``'--out is deprecated; use --output'``) to the namespace's
    ``NOTICES`` list, which the command line prints as one line before running the command.
    ``replacement`` names the new spelling; ``{}`` in it is replaced by the value given. An
    old positional argument (``nargs='?'``) notes only when it was given.
    """

    def __init__(self, option_strings: list[str], dest: str, *, replacement: str,
                 **kwargs: Any) -> None:
        kwargs['help'] = argparse.SUPPRESS
        super().__init__(option_strings, dest, **kwargs)
        self.replacement = replacement

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        """Store ``values`` under ``dest`` and note the old spelling."""
        setattr(namespace, self.dest, values)
        if values is None or values == []:
            return  # an optional positional left out
        new = self.replacement.format(values)
        old = option_string or f'{self.metavar or self.dest} as a positional argument'
        note(namespace, f'{old} is deprecated; use {new}')


def note(namespace: argparse.Namespace, notice: str) -> None:
    """Add a deprecation ``notice`` to the parsed ``namespace`` (printed once, before running)."""
    notices = list(getattr(namespace, NOTICES, None) or [])
    notices.append(notice)
    setattr(namespace, NOTICES, notices)


def wrap(text: str, width: int = HELP_WIDTH) -> str:
    """Fill each paragraph of a help text to ``width``; keep a paragraph with indented lines.

    For a parser with ``RawDescriptionHelpFormatter``: tables (indented) stay as written, and
    prose is wrapped here rather than left on one long line.
    """
    paragraphs = []
    for para in text.strip('\n').split('\n\n'):
        if any(line.startswith(' ') for line in para.splitlines()):
            paragraphs.append(para)
        else:
            paragraphs.append(textwrap.fill(' '.join(para.split()), width))
    return '\n\n'.join(paragraphs)
