"""The transport layer under the device drivers: I2C registers, framed serial links, TCP/UDP.

Each module opens one kind of link with bounded timeouts and a bounded retry count, and
turns every failure into ``enbarr_core.framework.errors.DeviceError`` naming the link (bus and
address, port, host and port). A driver (``enbarr_core.framework.driver``) catches that error,
puts its outputs in their safe state and reconnects with backoff. Each module has a fake or a
loopback twin so that a driver's byte-level logic is tested without the device.
"""
