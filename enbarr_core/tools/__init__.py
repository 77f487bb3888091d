"""Tools: headless scenarios on simulated time, their metrics, and the benchmarks."""
