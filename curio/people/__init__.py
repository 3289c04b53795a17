"""People among whom the rover drives: detection and tracking from the lidar, the controller's
people-aware stage, the polite guide and the tracking figures (docs/people.md)."""
