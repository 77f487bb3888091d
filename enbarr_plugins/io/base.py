"""Common part of IO plugins: act on ``io_request`` messages addressed to one executor.

An IO plugin has an executor name (what an ``io_request`` addresses): the stepper uses its
``executor`` parameter as is, the GPIO plugin makes ``gpio_<pin>``. Requests for other
executors are ignored; requests for this one with a value of the wrong type are refused, logged
and counted. After acting, the plugin publishes its new state on ``io_state`` under its
executor name.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import Parameter

from enbarr_core.framework.driver import DeviceNode
from enbarr_interfaces import convert, topics


class IoPluginNode(DeviceNode):
    """Base of IO plugins; see the module docstring.

    Subclasses set ``executor_name`` and implement ``act(value) -> str | None`` (a refusal);
    a real one opens its pins in ``open_device`` (``DeviceNode.start``), never in its
    constructor.
    """

    executor_name: str = ''

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.handled = 0
        self.refused = 0
        self._state_pub = self.create_topic_publisher(topics.IO_STATE)
        self.create_topic_subscription(topics.IO_REQUEST, self._on_request)

    def _on_request(self, msg: Parameter) -> None:
        if msg.name != self.executor_name:
            return
        value = convert.parameter_value_to_python(msg.value)
        reason = self.act(value)
        if reason:
            self.refused += 1
            self.get_logger().warn(f'{self.executor_name}: refused {value!r}: {reason}')
        else:
            self.handled += 1

    def act(self, value: Any) -> str | None:
        """Carry out one request addressed to this executor; return a refusal or None."""
        raise NotImplementedError

    def status_values(self) -> dict[str, Any]:
        """Return the executor name and the request counters."""
        return {'executor': self.executor_name, 'handled': self.handled,
                'refused': self.refused}

    def publish_state(self, value: Any) -> None:
        """Publish this executor's new state on ``io_state``."""
        self._state_pub.publish(Parameter(name=self.executor_name,
                                          value=convert.python_to_parameter_value(value)))
