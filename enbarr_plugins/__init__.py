"""Enbarr plugins: one module per hardware kind and device, each with a simulated twin."""
