"""BNO055 IMU: register map and conversions, smbus2 driver, fake I2C bus for emulation."""
