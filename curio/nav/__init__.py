"""Navigation and state estimation: maps, EKF, localisation, mapping, costmap, planning."""
