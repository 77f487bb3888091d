"""The plot of an ROV scenario, as a pilot reads one: depth, heading, forces, thrusters.

The CS Saucer's plot (``metrics.plot_run``) is drawn about a surface vessel's path, its
azimuths and its observer; an ROV's run is about depth and the pilot: left, the path seen from
above (north up) and the targets with the verdict; right, against time: depth (the truth and
the pressure sensor's), with the pilot-mode changes and the failsafes' actions marked;
heading; the controller's forces (surge, heave, yaw moment); each thruster's command.
``ROV_PLOT_TOPICS`` are what it reads besides ``metrics.METRIC_TOPICS``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from enbarr_interfaces import convert

#: What ``plot_rov_run`` reads besides ``metrics.METRIC_TOPICS``.
ROV_PLOT_TOPICS = ('/depth', '/pilot_mode', '/thruster_commands', '/failsafe/action')


def is_rov(profile: Any) -> bool:
    """Whether the profile flies the 6-DOF ROV (its simulator is ``rov_simulator``)."""
    return any(n.plugin == 'rov_simulator' for n in profile.nodes)


def _t(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def _events(ax: Any, events: list[tuple[float, str]], t0: float, colour: str,
            label: bool) -> None:
    """Mark each (time [s], what) with a vertical line and its name at the top."""
    for when, what in events:
        ax.axvline(when - t0, color=colour, lw=0.8, ls='--')
        if label:
            ax.text(when - t0, 1.0, f' {what}', transform=ax.get_xaxis_transform(),
                    rotation=90, va='top', fontsize=7, color=colour)


def plot_rov_run(msgs: dict[str, list[tuple[int, Any]]], profile: Any, png: Path,
                 verdict: dict[str, Any] | None) -> Path:
    """Draw the ROV's run from the bag's messages ``msgs`` into ``png`` and return it."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from enbarr_core.tools.metrics import _verdict_panel, NO_DATA, verdict_title

    odom = msgs['/sim/odometry']
    t = np.array([_t(m) for _, m in odom])
    t0 = t[0]
    xyz = np.array([(m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z)
                    for _, m in odom])
    yaw = np.degrees([convert.quaternion_to_yaw(m.pose.pose.orientation) for _, m in odom])
    # a mode or an action is stamped by its arrival in the bag (latched strings carry none)
    modes = [(ns * 1e-9, m.data) for ns, m in msgs.get('/pilot_mode', [])]
    actions = [(ns * 1e-9, m.data) for ns, m in msgs.get('/failsafe/action', [])]

    fig = plt.figure(figsize=(15, 15), layout='constrained')
    grid = fig.add_gridspec(4, 2)
    path = fig.add_subplot(grid[0:3, 0])
    path.plot(xyz[:, 0], xyz[:, 1], lw=1.2, label='vehicle (truth)')
    path.plot(xyz[:1, 0], xyz[:1, 1], 'go', label='start')
    path.plot(xyz[-1:, 0], xyz[-1:, 1], 'rs', label='end')
    path.set_aspect('equal', adjustable='datalim')
    path.set_xlabel('east [m] (odom x)')
    path.set_ylabel('north [m] (odom y)')
    path.set_title(f'{profile.name}: path seen from above, north up')
    path.legend(loc='best', fontsize=8)
    path.grid(True, alpha=0.3)
    _verdict_panel(fig.add_subplot(grid[3, 0]), verdict)

    depth_ax = fig.add_subplot(grid[0, 1])
    depth_ax.plot(t - t0, -xyz[:, 2], lw=1.2, label='depth (truth)')
    sensed = msgs.get('/depth', [])
    if sensed:
        depth_ax.plot([_t(m) - t0 for _, m in sensed],
                      [-m.pose.pose.position.z for _, m in sensed], '.', ms=2, alpha=0.5,
                      label='pressure sensor')
    _events(depth_ax, modes, t0, 'tab:purple', True)
    _events(depth_ax, [a for a in actions if a[1] != 'none'], t0, 'tab:red', True)
    depth_ax.invert_yaxis()   # deeper is down the page
    depth_ax.set_ylabel('depth [m]')
    depth_ax.set_title('depth; pilot modes (purple) and failsafe actions (red)')
    depth_ax.legend(loc='lower left', fontsize=8)
    depth_ax.grid(True, alpha=0.3)

    heading_ax = fig.add_subplot(grid[1, 1], sharex=depth_ax)
    heading_ax.plot(t - t0, yaw, lw=1.0)
    _events(heading_ax, modes, t0, 'tab:purple', False)
    heading_ax.set_ylabel('heading [deg] (ccw from east)')
    heading_ax.grid(True, alpha=0.3)

    force_ax = fig.add_subplot(grid[2, 1], sharex=depth_ax)
    forces = msgs.get('/force_command', [])
    if forces:
        ft = np.array([_t(m) - t0 for _, m in forces])
        tau = np.array([(m.wrench.force.x, m.wrench.force.z, m.wrench.torque.z)
                        for _, m in forces])
        for i, name in enumerate(('surge X [N]', 'heave Z [N] (up +)', 'yaw N [N m]')):
            force_ax.plot(ft, tau[:, i], lw=0.8, label=name)
        force_ax.legend(loc='upper right', fontsize=8)
    else:
        force_ax.text(0.5, 0.5, 'no force_command recorded', transform=force_ax.transAxes,
                      **NO_DATA)
    _events(force_ax, [a for a in actions if a[1] != 'none'], t0, 'tab:red', False)
    force_ax.set_ylabel("controller's force")
    force_ax.grid(True, alpha=0.3)

    thr_ax = fig.add_subplot(grid[3, 1], sharex=depth_ax)
    commands = msgs.get('/thruster_commands', [])
    if commands:
        ct = np.array([_t(m) - t0 for _, m in commands])
        names = list(commands[0][1].name)
        effort = np.array([list(m.effort) if len(m.effort) == len(names)
                           else [math.nan] * len(names) for _, m in commands])
        for i, name in enumerate(names):
            thr_ax.plot(ct, effort[:, i], lw=0.7, label=name)
        thr_ax.legend(loc='upper right', fontsize=7, ncol=2)
    else:
        thr_ax.text(0.5, 0.5, 'no thruster_commands recorded', transform=thr_ax.transAxes,
                    **NO_DATA)
    thr_ax.set_ylim(-1.05, 1.05)
    thr_ax.set_ylabel('thruster command (-1..1)')
    thr_ax.set_xlabel('time [s]')
    thr_ax.grid(True, alpha=0.3)
    verdict_title(fig, profile.name, verdict)
    fig.savefig(png, dpi=100)
    plt.close(fig)
    return png
