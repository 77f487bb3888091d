"""``enbarr chaos --profile P``: a profile run as a process tree, faults injected in turn.

The profile runs under ``enbarr bringup --output`` split into process groups, built on the
fly (``chaos.yaml`` in the output directory): the core nodes (command receiver, filter,
observer, guidance, controllers, allocation, PWM mapping) go to group ``control``, the rest
(simulator, sensor and actuator plugins, operator stand-ins) stay in ``main``, the recorder
gets its own. The split is what lets injection reach the nodes: a fast topic travels the
in-process link bus, and an outside publisher reaches a link subscription only when no
publisher of that topic lives in the subscriber's process (``enbarr_interfaces.links``).
The operator stand-in is given a steady command (an ROV drives ahead, a surface vessel holds
its pose in automatic) so that the actuators are busy when a fault comes.

Faults (``--faults`` selects kinds or names), each judged by ``chaos.judge`` from what a
subscriber in this process and the bag observe:

``stamps``
    For every stamped input of the control group (contract topics with a header that a
    control node subscribes to in the running graph: ``imu/data_raw``, ``imu/mag``,
    ``surface_command/twist``, ``mocap/pose``, ``joy``, ...): a burst of ten copies of
    the last real sample (a distinctive command on command topics) stamped +20 s, +0.4 s
    and -0.1 s from now.
    Safe: control not disrupted, and a command so stamped is never executed.
``compete``
    A second publisher on every command topic the profile has (``surface_command/twist``,
    ``surface_command/io``, ``joy``), sending a distinctive command for the window. Safe:
    control not disrupted and the intruder's command never executed (never the velocity
    goal, never an io request, never a surge force in manual: the joystick intruder presses
    manual and pushes surge, while manual with zero force is the safe outcome of a contested
    joystick).
``params``
    A parameter storm: for every node, ``SetParameters`` calls as ``ros2 param set`` makes
    them (one parameter per call, all at once): each parameter set to its own value
    (valid), to a value of the wrong type and, for floating-point ones, to NaN (invalid).
    Safe: control not disrupted, no invalid value accepted, and every call answered
    (``storm``: an unanswered call is a failure, judged with the others).
``sigstop`` / ``sigkill``
    The control group SIGSTOPped (SIGCONT after the window) / SIGKILLed (the supervisor
    restarts it). Safe: actuators neutral within 0.5 s. When none is seen in the window the
    fault is watched on, 5 s at most (a starved driver is measured late, not missed).
``disk``
    A second run recording to a 160 MiB tmpfs in a private mount namespace (needs root,
    else skipped), filled to the last byte once control runs. Safe: control not disrupted
    while the disk is full, the recorder's memory bounded, the bag readable, and
    ``bringup`` exiting non-zero.
``supervisor``
    The supervisor SIGKILLed (last: the run ends). Safe: actuators neutral within 0.5 s and
    the bag's last actuator output neutral.

Between faults the run waits until control is back (actuators busy again); a fault that left
control broken is followed by a SIGKILL of the control group, so the next fault starts clean.
Prints one JSON line (``judge.summary``) and exits 1 when a fault failed, a traceback
appeared in any process's output or a bag is unreadable.

The modules: ``plan`` (the split profile), ``tree`` (the bringup process tree), ``observer``
(the watching and injecting node), ``inputs``, ``storm``, ``removal`` and ``disk`` (the
faults, by kind), ``judge`` (pure: observations in, verdicts out) and ``run`` (a whole run,
fault after fault). The command line is ``enbarr_core.commands.chaos``.
"""
