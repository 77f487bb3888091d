"""Estimation: the IMU attitude filter and the DP observer, each beside its node."""
