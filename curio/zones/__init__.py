"""Zones drawn on the map: keep-out and speed-limit polygons, persisted per map, honoured by
the planner and the controller (through the costmap and a speed limit) and the safety stage,
and exported as Nav2 costmap-filter masks."""
