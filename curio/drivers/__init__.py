"""Device drivers: base link, RPLidar, BNO055, and their emulators."""
