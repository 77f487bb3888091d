"""Tools: headless scenarios on simulated time and their metrics, and fault injection (chaos/)."""
