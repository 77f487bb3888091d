"""Power sensing: the battery monitor (INA219) driver, its protocol and its emulator."""
