"""State estimation: EKF odometry fusion, localisation in a known map, mapping, map files and
laser-log formats, and the wiring that runs them on the bus."""
