"""The safety stage in front of the motors: limits, stop zone, command watchdog, e-stop."""
