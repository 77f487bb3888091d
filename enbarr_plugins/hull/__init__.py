"""Inside the hull: the enclosure's air pressure and temperature (BMP280), driver and emulator."""
