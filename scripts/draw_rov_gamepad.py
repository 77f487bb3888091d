"""The picture of the ROV gamepad (docs/rov_gamepad.png): a DualShock 4, what each control does.

    python3 scripts/draw_rov_gamepad.py [OUT.png]

The labels come from ``enbarr_core.control.rov_gamepad.GamepadSettings`` (the defaults that
``rov_gamepad`` and ``enbarr_rov_topside.yaml`` use), so a change of the mapping shows here
when the picture is drawn again. Matplotlib only (no image of the pad is copied in).
"""

from __future__ import annotations

import argparse
import sys

from enbarr_core.control.rov_gamepad import GamepadSettings

#: Where each DS4 control sits on the drawing (x, y in the pad's outline, 0..10 x 0..6).
PLACES: dict[str, tuple[float, float]] = {
    'left_stick': (3.4, 2.6), 'right_stick': (6.6, 2.6),
    'dpad_up': (2.0, 4.1), 'dpad_down': (2.0, 3.1), 'dpad_left': (1.5, 3.6),
    'dpad_right': (2.5, 3.6),
    'triangle': (8.0, 4.2), 'cross': (8.0, 3.0), 'square': (7.4, 3.6), 'circle': (8.6, 3.6),
    'l1': (2.0, 5.3), 'r1': (8.0, 5.3), 'l2': (2.0, 5.8), 'r2': (8.0, 5.8),
    'share': (3.3, 4.5), 'options': (6.7, 4.5), 'ps': (5.0, 2.9), 'trackpad': (5.0, 4.2),
    'l3': (3.4, 2.6), 'r3': (6.6, 2.6),
}

_WHAT = {
    'manual': 'pilot mode: manual', 'stabilize': 'pilot mode: stabilize',
    'depth_hold': 'pilot mode: depth hold', 'velocity': 'pilot mode: velocity',
    'lights': 'lights on/off', 'manipulator_open': 'manipulator +steps',
    'manipulator_close': 'manipulator -steps', 'tilt_up': 'camera tilt up',
    'tilt_down': 'camera tilt down', 'tilt_centre': 'camera tilt centre',
}


def labels(settings: GamepadSettings) -> dict[str, str]:
    """DS4 control -> what it does, for every stick and button the settings bind."""
    out: dict[str, list[str]] = {}
    full = dict(settings.full_stick)
    for dof, spec in settings.sticks:
        if not spec:
            continue
        name = spec.lstrip('-+')
        stick = name.rsplit('_', 1)[0] + '_stick'
        unit = 'rad/s' if dof == 'yaw' else 'm/s'
        way = {'left_x': 'left/right', 'right_x': 'left/right'}.get(name, 'up/down')
        out.setdefault(stick, []).append(f'{way}: {dof} ({full[dof]:g} {unit})')
    for control, button in settings.buttons:
        if button:
            press = ' (press)' if button in ('l3', 'r3') else ''
            out.setdefault(button, []).append(_WHAT[control] + press)
    return {k: '\n'.join(v) for k, v in out.items()}


def draw(path: str, settings: GamepadSettings) -> None:
    """Draw the pad with its labels into ``path`` (PNG)."""
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib import pyplot as plt
    from matplotlib.patches import Circle, FancyBboxPatch

    fig, ax = plt.subplots(figsize=(13, 7.5))
    ax.set_xlim(-4.5, 14.5)
    ax.set_ylim(-1.0, 8.0)
    ax.set_aspect('equal')
    ax.axis('off')
    for x in (1.2, 7.0):   # the grips, under the body
        ax.add_patch(FancyBboxPatch((x, 0.2), 1.8, 2.0, boxstyle='round,pad=0.4',
                                    fc='#e8e8ee', ec='#333'))
    ax.add_patch(FancyBboxPatch((0.6, 1.4), 8.8, 3.9, boxstyle='round,pad=0.4',
                                fc='#e8e8ee', ec='#333'))
    ax.add_patch(FancyBboxPatch((3.9, 3.7), 2.2, 1.1, boxstyle='round,pad=0.1', fc='#d0d0da',
                                ec='#555'))
    for name in ('left_stick', 'right_stick'):
        ax.add_patch(Circle(PLACES[name], 0.55, fc='#555', ec='#222'))
    for name, (x, y) in PLACES.items():
        if name.endswith('_stick') or name in ('l3', 'r3', 'trackpad'):
            continue
        ax.add_patch(Circle((x, y), 0.22, fc='#fafafa', ec='#333'))
        short = {'triangle': '△', 'cross': '✕', 'square': '□', 'circle': '○'}.get(
            name, name.replace('dpad_', '').replace('share', 'sh').replace('options', 'op')
            .upper()[:2])
        ax.text(x, y, short, ha='center', va='center', fontsize=7)
    text = labels(settings)
    for name, label in sorted(text.items()):
        x, y = PLACES[name]
        left = x < 5.0
        tx = -4.3 if left else 10.6
        ty = {'left_stick': 0.4, 'right_stick': 0.4, 'l3': 1.3, 'r3': 1.3}.get(name, y + 1.2)
        if name.startswith('dpad_'):
            ty = {'dpad_up': 4.6, 'dpad_down': 3.1}.get(name, 3.8)
        if name in ('cross', 'square', 'circle', 'triangle'):
            ty = {'triangle': 4.9, 'circle': 4.1, 'cross': 2.6, 'square': 3.3}[name]
        if name in ('l1', 'r1', 'l2', 'r2', 'share', 'options'):
            ty = {'l1': 6.4, 'r1': 6.4, 'l2': 7.4, 'r2': 7.4, 'share': 5.8, 'options': 5.8}[name]
        ax.annotate(f'{name}: {label}', (x, y), (tx, ty), fontsize=9,
                    ha='left', va='center',
                    arrowprops={'arrowstyle': '-', 'color': '#777', 'lw': 0.8})
    ax.set_title('Enbarr ROV gamepad (rov_gamepad, layout enbarr_ds4): sticks are velocity '
                 'goals, buttons act on the press', fontsize=11)
    fig.savefig(path, dpi=110, bbox_inches='tight')
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Write the picture; the path defaults to docs/rov_gamepad.png."""
    parser = argparse.ArgumentParser(description=(__doc__ or '').split('\n')[0])
    parser.add_argument('output', nargs='?', default='docs/rov_gamepad.png',
                        help='the PNG to write')
    args = parser.parse_args(argv)
    draw(args.output, GamepadSettings())
    return 0


if __name__ == '__main__':
    sys.exit(main())
