"""What blocks the rover, for the map while it asks for help.

:func:`find_blocker` takes the latest scan, the rover's pose in ``map`` and its plan, and
returns the scan points that lie in the rover's way: in a corridor as wide as the footprint
(plus a margin) along the direction of travel, up to a little beyond the obstacle distance the
blocked-path detector reported. The page draws them (red) with the distance, so the operator
sees what to clear instead of guessing.

Units: metres and radians; points in ``map``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from curio.core.geometry import Pose2D
from curio.core.messages import BlockedState, LaserScan, Path
from curio.robot import RobotModel

__all__ = ["MAX_POINTS", "find_blocker", "travel_heading"]

# At most this many points are sent to the page.
MAX_POINTS = 240
# The corridor is the footprint's half width plus this margin on each side, metres.
SIDE_MARGIN_M = 0.15
# How far to look when the detector gave no distance, and beyond the distance it gave, metres.
DEFAULT_REACH_M = 1.2
EXTRA_REACH_M = 0.4


def travel_heading(pose: Pose2D, plan: Path | None, ahead_m: float = 0.6) -> float:
    """The direction of travel in map, rad: towards the plan point about ``ahead_m`` past the
    nearest one, else the rover's own heading."""
    if plan is None or len(plan.poses) < 2:
        return pose.yaw
    xy = np.array([(p.x, p.y) for p in plan.poses])
    d = np.hypot(xy[:, 0] - pose.x, xy[:, 1] - pose.y)
    start = int(np.argmin(d))
    seg = np.hypot(np.diff(xy[start:, 0]), np.diff(xy[start:, 1]))
    j = min(start + int(np.searchsorted(np.cumsum(seg), ahead_m)) + 1, len(xy) - 1)
    dx, dy = xy[j, 0] - pose.x, xy[j, 1] - pose.y
    return pose.yaw if math.hypot(dx, dy) < 0.05 else math.atan2(dy, dx)


def find_blocker(scan: LaserScan | None, pose: Pose2D | None, plan: Path | None,
                 blocked: BlockedState | None, robot: RobotModel) -> dict[str, Any] | None:
    """``{points: [[x, y], ...] in map, distance_m, reason}`` of what is in the rover's way, or
    None without a scan or a pose."""
    if scan is None or pose is None:
        return None
    pts = scan.points(robot.laser_in_base)  # base_link
    if len(pts) == 0:
        return None
    heading = travel_heading(pose, plan) - pose.yaw
    c, s = math.cos(heading), math.sin(heading)
    along = pts[:, 0] * c + pts[:, 1] * s
    across = -pts[:, 0] * s + pts[:, 1] * c
    footprint = np.asarray(robot.footprint_points, dtype=np.float64)
    half_width = float(np.max(np.abs(footprint[:, 1]))) + SIDE_MARGIN_M
    front = float(np.max(footprint[:, 0]))
    distance = blocked.obstacle_distance_m if blocked is not None else None
    reach = front + (distance + EXTRA_REACH_M if distance is not None else DEFAULT_REACH_M)
    mask = (along > 0.0) & (along <= reach) & (np.abs(across) <= half_width)
    chosen = pts[mask]
    if len(chosen) > MAX_POINTS:
        chosen = chosen[:: math.ceil(len(chosen) / MAX_POINTS)]
    in_map = pose.transform_points(chosen) if len(chosen) else np.zeros((0, 2))
    return {"points": np.round(in_map, 3).tolist(),
            "distance_m": None if distance is None else round(distance, 2),
            "reason": blocked.reason if blocked is not None else ""}
