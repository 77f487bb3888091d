"""Pressure plugins: the MS5837-30BA depth sensor (Blue Robotics Bar30) and its emulator."""
