"""Operator stand-ins: scripted surface commands and keyboard teleoperation."""
