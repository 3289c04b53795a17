"""Dynamic objects of the simulated world: boxes, people on scripted routes, doors.

All coordinates are in ``map`` (metres, radians). Every object can give its outline for ray
casting (segments, circles) and answer collision queries against the rover footprint.
Objects are plain data plus pure geometry; the :class:`~curio.sim.world.World` owns and moves
them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = [
    "Box",
    "Door",
    "Person",
    "circle_hits_polygon",
    "point_in_polygon",
    "polygons_overlap",
    "rect_corners",
]

Point = tuple[float, float]


def rect_corners(x_m: float, y_m: float, w_m: float, h_m: float, yaw_rad: float) -> list[Point]:
    """Corners (counter-clockwise) of a ``w × h`` rectangle centred at (x, y), rotated by yaw."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    hw, hh = 0.5 * w_m, 0.5 * h_m
    return [(x_m + c * px - s * py, y_m + s * px + c * py)
            for px, py in ((hw, hh), (-hw, hh), (-hw, -hh), (hw, -hh))]


def _axes(poly: list[Point]) -> list[Point]:
    out = []
    n = len(poly)
    for i in range(n):
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % n]
        out.append((y1 - y2, x2 - x1))
    return out


def polygons_overlap(a: list[Point], b: list[Point]) -> bool:
    """Whether two convex polygons overlap (separating-axis test; touching counts)."""
    for ax, ay in _axes(a) + _axes(b):
        pa = [ax * x + ay * y for x, y in a]
        pb = [ax * x + ay * y for x, y in b]
        if max(pa) < min(pb) or max(pb) < min(pa):
            return False
    return True


def point_in_polygon(px: float, py: float, poly: list[Point]) -> bool:
    inside = False
    n = len(poly)
    for i in range(n):
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % n]
        if (y1 > py) != (y2 > py):
            xc = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
            if px < xc:
                inside = not inside
    return inside


def _dist_point_segment(px: float, py: float, a: Point, b: Point) -> float:
    ex, ey = b[0] - a[0], b[1] - a[1]
    ll = ex * ex + ey * ey
    u = 0.0 if ll == 0.0 else max(0.0, min(1.0, ((px - a[0]) * ex + (py - a[1]) * ey) / ll))
    return math.hypot(px - a[0] - u * ex, py - a[1] - u * ey)


def circle_hits_polygon(cx: float, cy: float, r: float, poly: list[Point]) -> bool:
    """Whether a circle overlaps a polygon (inside, or closer than ``r`` to an edge)."""
    if point_in_polygon(cx, cy, poly):
        return True
    n = len(poly)
    return any(_dist_point_segment(cx, cy, poly[i], poly[(i + 1) % n]) <= r for i in range(n))


def _edges(poly: list[Point]) -> list[tuple[float, float, float, float]]:
    n = len(poly)
    return [(poly[i][0], poly[i][1], poly[(i + 1) % n][0], poly[(i + 1) % n][1])
            for i in range(n)]


@dataclass
class Box:
    """A rectangular obstacle: centre (x, y) m, size ``w × h`` m along its own axes, yaw rad."""

    x_m: float
    y_m: float
    w_m: float
    h_m: float
    yaw_rad: float = 0.0

    def polygon(self) -> list[Point]:
        """Outline corners in ``map``."""
        return rect_corners(self.x_m, self.y_m, self.w_m, self.h_m, self.yaw_rad)

    def segments(self) -> list[tuple[float, float, float, float]]:
        """Outline edges (x1, y1, x2, y2) for ray casting."""
        return _edges(self.polygon())

    def bounding_radius_m(self) -> float:
        """Radius of the circle around the centre that holds the box."""
        return 0.5 * math.hypot(self.w_m, self.h_m)


@dataclass
class Person:
    """A person walking a polyline route at ``speed_mps`` (a circle of ``radius_m``).

    ``loop``: after the last point walk back to the first; otherwise stop there. ``wait_s``:
    pause at each route point. A person never walks into the rover: they wait while their
    next position would touch the footprint, and after a while (the world's patience) turn
    back along their route (:meth:`turn_back`), as people do when a way stays blocked.
    """

    route: list[Point]
    speed_mps: float = 0.8
    radius_m: float = 0.25
    loop: bool = True
    wait_s: float = 0.0
    start_delay_s: float = 0.0
    x_m: float = 0.0
    y_m: float = 0.0
    _leg: int = 0
    _pause_s: float = 0.0
    _done: bool = False
    _backwards: bool = False
    waited_s: float = 0.0  # how long they have been waiting for the rover, s (the world's)

    def __post_init__(self) -> None:
        if not self.route:
            raise ValueError("a person needs a route of at least one [x, y] point")
        if self.speed_mps < 0.0 or self.radius_m <= 0.0:
            raise ValueError("a person needs speed_mps >= 0 and radius_m > 0")
        self.x_m, self.y_m = self.route[0]
        self._pause_s = self.start_delay_s

    def next_position(self, dt_s: float) -> tuple[float, float, int, float, bool, bool]:
        """Where the person would be after ``dt_s`` (x, y, leg, pause, done, walking back),
        not applied."""
        x, y, leg, pause, done = self.x_m, self.y_m, self._leg, self._pause_s, self._done
        back = self._backwards
        n = len(self.route)
        if done or n < 2:
            return x, y, leg, pause, True, back
        if pause > 0.0:
            return x, y, leg, max(0.0, pause - dt_s), done, back
        travel = self.speed_mps * dt_s
        while travel > 1e-12:
            # Walking leg ``leg`` (route[leg] -> route[leg + 1]), or back along it.
            target = self.route[leg] if back else self.route[(leg + 1) % n]
            dist = math.hypot(target[0] - x, target[1] - y)
            if dist > travel:
                x += (target[0] - x) * travel / dist
                y += (target[1] - y) * travel / dist
                break
            x, y = target
            travel -= dist
            if back:
                if not self.loop and leg == 0:
                    back = False  # back where they started: they try the way again
                else:
                    leg = (leg - 1) % n
            else:
                leg = (leg + 1) % n
                if not self.loop and leg == n - 1:
                    return x, y, leg, 0.0, True, back
            if self.wait_s > 0.0:
                return x, y, leg, self.wait_s, done, back
        return x, y, leg, pause, done, back

    def turn_back(self) -> None:
        """Walk the other way along the route from here (the way ahead stayed blocked)."""
        if len(self.route) >= 2 and not self._done:
            if not self.loop and not self._backwards and self._leg >= len(self.route) - 1:
                return
            self._backwards = not self._backwards
        self.waited_s = 0.0

    def commit(self, state: tuple[float, float, int, float, bool, bool]) -> None:
        """Apply a state returned by :meth:`next_position`."""
        self.x_m, self.y_m, self._leg, self._pause_s, self._done, self._backwards = state


@dataclass
class Door:
    """A named door leaf across a doorway: a ``thickness_m`` slab from ``a`` to ``b`` (map, m).

    Closed, it blocks motion and beams; open, it is out of the way. ``script`` holds
    ``(t_s, open)`` pairs the world applies at those simulated times.
    """

    name: str
    a: Point
    b: Point
    is_open: bool = True
    thickness_m: float = 0.05
    script: list[tuple[float, bool]] = field(default_factory=list)

    def polygon(self) -> list[Point]:
        """The closed leaf's outline corners in ``map``."""
        (x1, y1), (x2, y2) = self.a, self.b
        length = math.hypot(x2 - x1, y2 - y1)
        return rect_corners(0.5 * (x1 + x2), 0.5 * (y1 + y2), length, self.thickness_m,
                            math.atan2(y2 - y1, x2 - x1))

    def segments(self) -> list[tuple[float, float, float, float]]:
        """Outline edges for ray casting (empty when open)."""
        return [] if self.is_open else _edges(self.polygon())

    @property
    def centre(self) -> Point:
        """Midpoint of the doorway, metres."""
        return (0.5 * (self.a[0] + self.b[0]), 0.5 * (self.a[1] + self.b[1]))
