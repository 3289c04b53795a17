"""Navigation: cost values, costmap, global planner, local controller, recovery, the navigator
(goals with action semantics), obstacle and blocked-path detection."""
