"""The servo battery: state of charge and time left from the pack's voltage curve, the levels
(ok, low, critical) with hysteresis, and the monitor that publishes ``/power``."""
