"""BNO055 IMU: register map and conversions (``protocol``), the smbus2 driver (``driver``) and
the emulator on a fake I2C bus (``emulator``)."""
