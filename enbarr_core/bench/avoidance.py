"""``enbarr bench --avoidance``: what the CBF safety filters cost per step.

Times ``SafetyFilter.step`` (``enbarr_core.guidance.cbf``) on the Saucer-sized settings with
``--obstacles`` capsules (circles and walls) in three cases, each the median of ``--repeat``
runs of many steps: ``far`` (no barrier binds: the identity, no QP), ``engaged`` (the
desired position pressed against the obstacles: one or two daqp solves per step) and the
bare ``daqp.solve`` of such a QP; and the force-level ``ForceSafetyFilter.step``
(``enbarr_core.guidance.force_cbf``, the model of ``params/saucer_core.yaml``) far and
engaged (the vessel closing on an obstacle, pushed into it: one or two solves). Prints one
JSON line with microseconds per step, each level's share of one core at 50 Hz (its worse
case), and the Pi 4 estimates (x6, docs/benchmarks.md).
"""

from __future__ import annotations

import math
import statistics
import time
from typing import Any

import numpy as np

#: A Raspberry Pi 4 core runs CPython about this much slower (docs/benchmarks.md).
PI4_FACTOR = 6
DEFAULT_OBSTACLES = 10
DEFAULT_REPEAT = 5
CONTROL_RATE = 50.0        # the Saucer's estimate rate [Hz]
STEPS = 2000


def _world(k: int, rng: np.random.Generator) -> Any:
    """Place k obstacles 1-3 m around the origin, a quarter of them walls."""
    rows = []
    for i in range(k):
        a = 2.0 * math.pi * i / max(k, 1)
        r = rng.uniform(1.0, 3.0)
        x, y = r * math.cos(a), r * math.sin(a)
        x2, y2 = (x + rng.uniform(-0.5, 0.5), y + rng.uniform(-0.5, 0.5)) if i % 4 == 0 \
            else (x, y)
        rows.append((x, y, x2, y2, rng.uniform(0.1, 0.3), 0.0, 0.0))
    return np.array(rows, dtype=float).reshape(-1, 7)


def _time_steps(case: str, k: int) -> float:
    """Microseconds per filter step for ``case`` ('far' or 'engaged') with k obstacles."""
    from enbarr_core.guidance.cbf import CbfSettings, SafetyFilter
    from enbarr_core.guidance.guidance import LosPath
    rng = np.random.default_rng(1)
    world = _world(k, rng)
    settings = CbfSettings(safety_radius=0.2, vessel_radius=0.1375, tracking_margin=0.2)
    if case == 'far':
        world[:, 0:4] += 100.0
    f = SafetyFilter(settings)
    law = LosPath([(0.0, 0.0), (10.0, 0.0)], 0.2, 0.5, 0.1)
    eta = np.zeros(3)
    nominal = law.reference(eta, 0.02)
    if case == 'engaged':   # pressed against the first obstacle: the QP every step
        c = world[0, 0:2]
        f.engage_at(c - (world[0, 4] + settings.margin + 0.01) * c / np.linalg.norm(c))
    start = time.perf_counter()
    pressed = f.p_d
    for _ in range(STEPS):
        if case == 'engaged':   # stays pressed: the state is reset, not the cost
            f.p_d, f.v = pressed, (0.0, 0.0)
        f.step(eta, nominal, world, 0.02)
    return (time.perf_counter() - start) / STEPS * 1e6


def _time_force(case: str, k: int) -> float:
    """Microseconds per force-filter step for ``case`` ('far' or 'engaged'), k obstacles."""
    from enbarr_core.bringup.profile import load_profile
    from enbarr_core.guidance.force_cbf import ForceCbfSettings, ForceSafetyFilter
    world = _world(k, np.random.default_rng(1))
    if case == 'far':
        world[:, 0:4] += 100.0
    v = load_profile('saucer_core', allow_fragment=True).parameters
    f = ForceSafetyFilter(ForceCbfSettings(
        tuple(v['vessel.inertia']), tuple(v['vessel.linear_damping']),
        tuple(v['vessel.nonlinear_damping']), (2.0, 2.0, 0.3), safety_radius=0.2,
        vessel_radius=0.1375, a1=0.5, a2=0.5, pass_gain=1.0))
    c = world[0, 0:2]
    ahead = c / np.linalg.norm(c)
    # 1 cm outside the first obstacle's zone, facing it, closing at 0.1 m/s, pushed at 2 N.
    p = c - (world[0, 4] + 0.1375 + 0.2 + 0.01) * ahead
    eta = np.array((p[0], p[1], math.atan2(ahead[1], ahead[0])))
    nu, tau = np.array((0.1, 0.0, 0.0)), np.array((2.0, 0.0, 0.0))
    start = time.perf_counter()
    for _ in range(STEPS):
        f.step(eta, nu, tau, world)
    return (time.perf_counter() - start) / STEPS * 1e6


def _time_daqp(k: int) -> float:
    """Microseconds per bare daqp.solve of a QP of the filter's shape (k + 8 rows)."""
    import daqp
    rng = np.random.default_rng(2)
    A = rng.normal(size=(k + 8, 2))
    bu = np.full(k + 8, 1e30)
    bl = rng.uniform(-1.0, 0.0, k + 8)
    sense = np.zeros(k + 8, dtype=np.int32)
    H, f = np.eye(2), np.array([-0.2, 0.0])
    start = time.perf_counter()
    for _ in range(STEPS):
        daqp.solve(H, f, A, bu, bl, sense)
    return (time.perf_counter() - start) / STEPS * 1e6


def measure(obstacles: int = DEFAULT_OBSTACLES, repeat: int = DEFAULT_REPEAT) -> dict[str, Any]:
    """Run the cases ``repeat`` times each and return the medians (see the module doc)."""
    from enbarr_core.bench.chain import machine
    us = {
        'far': statistics.median(_time_steps('far', obstacles) for _ in range(repeat)),
        'engaged': statistics.median(_time_steps('engaged', obstacles) for _ in range(repeat)),
        'daqp_solve': statistics.median(_time_daqp(obstacles) for _ in range(repeat)),
        'force_far': statistics.median(_time_force('far', obstacles) for _ in range(repeat)),
        'force_engaged': statistics.median(_time_force('engaged', obstacles)
                                           for _ in range(repeat)),
    }
    worst = max(us['far'], us['engaged'])
    share = worst * 1e-6 * CONTROL_RATE * 100.0
    force = max(us['force_far'], us['force_engaged']) * 1e-6 * CONTROL_RATE * 100.0
    return {'bench': 'avoidance', 'machine': machine(), 'obstacles': obstacles,
            'us_per_step': {k: round(v, 1) for k, v in us.items()},
            'core_percent_at_50hz': round(share, 3),
            'pi4_estimate_core_percent_at_50hz': round(share * PI4_FACTOR, 2),
            'force_core_percent_at_50hz': round(force, 3),
            'force_pi4_estimate_core_percent_at_50hz': round(force * PI4_FACTOR, 2)}
