"""The built-in simulator: world, rover physics, lidar ray casting, IMU."""
