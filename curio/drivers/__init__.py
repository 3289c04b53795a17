"""Device drivers: base link (kinematics, odometry, Arduino protocol), RPLidar, BNO055, emulators."""
