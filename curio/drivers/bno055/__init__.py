"""BNO055 IMU: register map and conversions, smbus2 driver, emulator on a fake I2C bus and its
part of ``curio check`` (``protocol``, ``driver``, ``emulator``, ``check``)."""
