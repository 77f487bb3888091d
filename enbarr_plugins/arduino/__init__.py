"""Arduino PWM boards driving azimuth ESCs and servos: ``sim`` is a simulated one."""
