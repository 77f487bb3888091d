"""IO plugins: GPIO outputs and steppers, addressed by executor name."""
