"""A driver node and its emulator node in one executor, with a probe (IMU node tests)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
import itertools
import math
from typing import Any

import numpy as np
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu

from enbarr_core.framework.kinematics import quat_from_euler
from enbarr_core.framework.node import EnbarrNode
from enbarr_interfaces import convert, topics
from enbarr_plugins import emulation
from enbarr_plugins.transport.i2c import FakeI2cBus
from support.devices import diagnostics_of
from support.waiting import spin_until

TIMEOUT = 10.0
_names = itertools.count()


def assert_ranges(table: Any, typed: dict[float, tuple[int, float]], unit: float) -> None:
    """Assert a protocol module's full-scale table (full scale -> (code, sensitivity)) is
    ``typed``: the same full scales, codes, and sensitivities (typed ones x ``unit``)."""
    assert set(table) == set(typed)
    for full_scale, (code, lsb) in typed.items():
        assert table[full_scale][0] == code, full_scale
        assert math.isclose(table[full_scale][1], lsb * unit, rel_tol=1e-9), (
            full_scale, table[full_scale][1], lsb * unit)


def close_in_scale(measured: Any, expected: Any, tolerance: float) -> None:
    """Assert every component within ``tolerance`` x the largest expected one.

    For readings through an emulator that adds (seeded) noise of a fixed size per component.
    """
    np.testing.assert_allclose(measured, expected, rtol=0.0,
                               atol=tolerance * np.abs(expected).max())


@contextmanager
def registered(bus: FakeI2cBus) -> Iterator[str]:
    """``bus`` as an emulated bus of this process: yields the drivers' ``bus`` parameter."""
    name = f'imu-unit-{next(_names)}'
    emulation.register('i2c', name, bus)
    try:
        yield f'emulated:{name}'
    finally:
        emulation.unregister('i2c', name)


class Rig:
    """Emulator node, driver node, and a probe that publishes truth and records samples."""

    def __init__(self, context: Any, executor: Any, driver: type, emulator_class: type, *,
                 emulator: bool = True, start: bool = True, **params: Any) -> None:
        self.context, self.executor = context, executor
        self.emulator_class = emulator_class
        self.name = f'imu-node-{next(_names)}'
        self.raw: list[Imu] = []
        self.mag: list[Any] = []
        self.probe = EnbarrNode('probe', context=context)
        executor.add_node(self.probe)
        self.diag = diagnostics_of(self.probe, 'imu')
        self.truth_pub = self.probe.create_topic_publisher(topics.SIM_IMU)
        self.probe.create_topic_subscription(topics.IMU_RAW, self.raw.append)
        self.probe.create_topic_subscription(topics.IMU_MAG, self.mag.append)
        self.emulator = self.add_emulator() if emulator else None
        overrides = {'bus': f'emulated:{self.name}', 'rate': 100.0,
                     'reconnect.initial_delay': 0.05, 'reconnect.max_delay': 0.2,
                     'data_timeout': 0.3}
        overrides.update(params)
        self.driver = driver(
            context=context, parameter_overrides=[Parameter(k, value=v)
                                                  for k, v in overrides.items()])
        executor.add_node(self.driver)
        if start:
            self.driver.start()

    def add_emulator(self, start: bool = True) -> Any:
        """Build the emulator node (and start it: its chips go on the bus then)."""
        node = self.emulator_class(context=self.context, parameter_overrides=[
            Parameter('name', value=self.name),
            Parameter('gyro_bias', value=[0.0, 0.0, 0.0])])
        self.executor.add_node(node)
        if start:
            node.start()
        self.emulator = node
        return node

    @property
    def bus(self) -> FakeI2cBus:
        return self.emulator.bus

    def spin_until(self, condition, timeout: float = TIMEOUT) -> bool:
        return spin_until(self.executor, condition, timeout, step=0.02)

    def publishing(self) -> bool:
        """True once new samples arrive (waits for two)."""
        n = len(self.raw)
        return self.spin_until(lambda: len(self.raw) >= n + 2)

    def truth(self, rpy, omega, f) -> None:
        msg = Imu()
        msg.header.frame_id = topics.IMU_FRAME
        convert.set_quaternion(msg.orientation, quat_from_euler(*rpy))
        convert.set_vector3(msg.angular_velocity, omega)
        convert.set_vector3(msg.linear_acceleration, f)
        self.truth_pub.publish(msg)
