"""Write a calibrated frame back into the profile file that declares it, keeping the rest.

A calibration (``enbarr calibrate lidar``) moves one static frame of a profile's ``frames``
section. The entry is rewritten in place, as a one-line flow mapping in the form
``frames.py`` parses (``{parent: ..., xyz: [x, y, z], rpy: [roll, pitch, yaw]}``, translation
[m], roll-pitch-yaw [rad] about the parent's fixed axes), and every other byte of the file is
left as it was: comments, order, layout. PyYAML keeps no comments, so the entry's span is
found from the composer's marks and replaced as text; the comment at the end of the entry's
line, if any, becomes ``note`` (an ESTIMATE mark would otherwise stay on a measured value).

The file written is the one that set the entry (an included fragment such as
``saucer_core.yaml`` when the vessel profile includes it); when another file also sets keys
of that entry the merge would hide the write, so that is refused, and ``write_fragment``
writes a small include-only file instead (``include:`` it last in the vessel profile).
After writing, the profile is loaded again and must give the written transform, or the
file is restored.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import re
from typing import Any

import yaml

from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.errors import ProfileError
from enbarr_core.framework.frames import Transform

#: Digits written: 0.01 mm and 1 microradian, far below what a calibration resolves.
XYZ_DIGITS = 5
RPY_DIGITS = 6


@dataclass(frozen=True)
class Written:
    """Where a frame was written and how it reads back."""

    path: str
    frame: str
    entry: str            # the flow mapping written
    transform: Transform  # as the profile loader reads it back


def entry_text(parent: str, transform: Transform, rotation_key: str = 'rpy') -> str:
    """Return the flow mapping of a static frame: ``{parent: P, xyz: [...], rpy: [...]}``."""
    xyz = ', '.join(_num(v, XYZ_DIGITS) for v in transform.translation)
    if rotation_key == 'quaternion':
        rot = ', '.join(_num(v, 9) for v in transform.rotation)
    else:
        rot = ', '.join(_num(v, RPY_DIGITS) for v in transform.rpy)
    return f'{{parent: {parent}, xyz: [{xyz}], {rotation_key}: [{rot}]}}'


def _num(v: float, digits: int) -> str:
    r = round(float(v), digits)
    return repr(0.0 if r == 0 else r)


def write_frame(profile: str, frame: str, transform: Transform, *,
                note: str = '') -> Written:
    """Set static ``frame``'s pose in its parent to ``transform`` in the file declaring it.

    ``profile`` is the vessel profile (name or path) whose tree the frame belongs to.
    ``ProfileError`` naming the file and key when the frame is not declared in a file, is
    dynamic, or is set by more than one file.
    """
    prof = load_profile(profile, allow_fragment=True)
    f = prof.frames.frame(frame)
    if f.parent is None or f.dynamic:
        raise ProfileError(f'frame {frame!r} is the root or dynamic: a calibration writes a '
                           'static frame', path=prof.path, key=f'frames.{frame}')
    key = f'frames.{frame}'
    target = prof.where(key)
    others = sorted({v for k, v in prof.origins.items()
                     if (k == key or k.startswith(key + '.')) and v != target})
    if others:
        raise ProfileError(f'{key} is set in {target} and in {", ".join(others)}: write the '
                           'result as a fragment (--fragment) or keep the entry in one file',
                           path=target, key=key)
    path = Path(target)
    text = path.read_text()
    start, end, old = _entry_span(text, frame, str(path))
    rotation_key = 'quaternion' if 'quaternion' in old else 'rpy'
    entry = entry_text(f.parent, transform, rotation_key)
    line_end = text.find('\n', end)
    line_end = len(text) if line_end < 0 else line_end
    tail = text[end:line_end]
    if note and re.fullmatch(r'\s*#.*', tail):
        tail = re.match(r'\s*', tail).group(0) + '# ' + note  # type: ignore[union-attr]
    elif note and not tail.strip():
        tail = '  # ' + note
    new = text[:start] + entry + tail + text[line_end:]
    path.write_text(new)
    try:
        back = load_profile(profile, allow_fragment=True).frames.frame(frame).transform
        if not back.is_close(transform, tol=1e-4):
            raise ProfileError(f'{key} reads back as {back}, not {transform}', path=target)
    except Exception:
        path.write_text(text)
        raise
    return Written(target, frame, entry, back)


def write_fragment(path: str, frame: str, parent: str, transform: Transform, *,
                   note: str = '', rotation_key: str = 'rpy') -> str:
    """Write an include-only profile holding ``frames.<frame>`` alone; return its text.

    The profile merges it key by key over the entry it already has, so the rotation must be
    given in the same form (``rpy`` or ``quaternion``) as there.
    """
    lines = [f'# {note}' if note else '# A calibrated frame (enbarr calibrate lidar).',
             '# Include it last in the vessel profile: include: [..., '
             f'{Path(path).name}]',
             f'profile: {Path(path).stem}',
             'description: calibrated frames',
             'fragment: true',
             'frames:',
             f'  {frame}: {entry_text(parent, transform, rotation_key)}', '']
    text = '\n'.join(lines)
    Path(path).write_text(text)
    return text


def _entry_span(text: str, frame: str, where: str) -> tuple[int, int, str]:
    """Start and end offsets of ``frames.<frame>``'s value in ``text``, and its text."""
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as err:
        raise ProfileError(f'not YAML: {err}', path=where) from err
    frames = _child(root, 'frames')
    value = _child(frames, frame) if frames is not None else None
    if value is None:
        raise ProfileError(f'no frames.{frame} entry in this file', path=where)
    if not isinstance(value, yaml.MappingNode):
        raise ProfileError('expected a mapping', path=where, key=f'frames.{frame}')
    start = value.start_mark.index
    end = _end(value)
    return start, end, text[start:end]


def _child(node: Any, key: str) -> Any:
    if not isinstance(node, yaml.MappingNode):
        return None
    for k, v in node.value:
        if isinstance(k, yaml.ScalarNode) and k.value == key:
            return v
    return None


def _end(node: Any) -> int:
    """Where ``node``'s own text ends: a block collection's marks run on to the next token."""
    if isinstance(node, yaml.MappingNode) and not node.flow_style and node.value:
        return _end(node.value[-1][1])
    if isinstance(node, yaml.SequenceNode) and not node.flow_style and node.value:
        return _end(node.value[-1])
    end: int = node.end_mark.index
    return end
