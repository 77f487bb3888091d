"""Arduino PWM boards: ``sim`` is the simulated board of the CS Saucer."""
