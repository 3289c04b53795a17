"""Cost values and the inflation formula: the one home of the costmap's semantics.

Like Nav2's ``cost_values.hpp``, every module that reads or writes costs (the costmap, the
planner, the controller, the navigator, recovery, scenarios) uses these names and functions;
none spells a number.

Costs are ``uint8``:

* ``FREE_SPACE`` (0) — nothing near;
* ``1 .. MAX_NON_OBSTACLE`` (252) — inflated: the centre is within the inflation radius of an
  obstacle, the cost falling exponentially with the distance;
* ``INSCRIBED`` (253) — the rover's centre here means a certain collision (the distance to an
  obstacle is within the footprint's inscribed radius);
* ``LETHAL`` (254) — an obstacle;
* ``NO_INFORMATION`` (255) — unknown space.

The inflation at distance ``d`` (metres, between cell centres) from the nearest lethal cell is
``LETHAL`` at ``d = 0``, ``INSCRIBED`` for ``0 < d <= r_in`` and
``floor(INSCRIBED · exp(−k · (d − r_in)))`` (at most ``MAX_NON_OBSTACLE``) for
``r_in < d <= inflation_radius_m``, 0 beyond; ``r_in`` is the padded footprint's inscribed
radius and ``k`` the ``cost_scaling_factor`` (1/m). :func:`distance_beyond_inscribed_m` is its
inverse.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
import numpy.typing as npt

from curio.core.geometry import Pose2D

__all__ = [
    "FREE_SPACE",
    "INSCRIBED",
    "LETHAL",
    "MAX_NON_OBSTACLE",
    "NO_INFORMATION",
    "CostGrid",
    "cost_at_distance",
    "distance_beyond_inscribed_m",
    "inflation_costs",
]

FREE_SPACE = 0
MAX_NON_OBSTACLE = 252
INSCRIBED = 253
LETHAL = 254
NO_INFORMATION = 255

U8Array = npt.NDArray[np.uint8]
FloatArray = npt.NDArray[np.float64]


def inflation_costs(distance_m: FloatArray, inscribed_m: float, inflation_radius_m: float,
                    cost_scaling_factor: float) -> U8Array:
    """Costs for distances (metres) to the nearest lethal cell (see the module docstring)."""
    d = np.asarray(distance_m, dtype=np.float64)
    out = np.zeros(d.shape, dtype=np.uint8)
    decay = (d > inscribed_m) & (d <= inflation_radius_m)
    if decay.any():
        vals = np.floor(INSCRIBED * np.exp(-cost_scaling_factor * (d[decay] - inscribed_m)))
        out[decay] = np.clip(vals, 0, MAX_NON_OBSTACLE).astype(np.uint8)
    out[(d > 0.0) & (d <= inscribed_m)] = INSCRIBED
    out[d <= 0.0] = LETHAL
    return out


def cost_at_distance(beyond_inscribed_m: float, cost_scaling_factor: float) -> float:
    """The inflation curve (before flooring and the cap at ``MAX_NON_OBSTACLE``) where the
    centre is ``beyond_inscribed_m`` metres further from an obstacle than the inscribed radius:
    a cell is at least that far exactly when its cost is below this value."""
    return INSCRIBED * math.exp(-cost_scaling_factor * max(0.0, beyond_inscribed_m))


def distance_beyond_inscribed_m(cost: int, cost_scaling_factor: float) -> float:
    """The inverse of the inflation: how far beyond the inscribed radius the centre of a cell
    of this cost is from the nearest obstacle, metres (``inf`` for free space, 0 at or above
    ``INSCRIBED``) — a lower bound of the footprint's clearance."""
    if cost <= FREE_SPACE:
        return math.inf
    if cost >= INSCRIBED:
        return 0.0
    return max(0.0, -math.log(cost / INSCRIBED) / cost_scaling_factor)


class CostGrid(Protocol):
    """The costmap as its readers see it (:class:`curio.nav.costmap.Costmap` implements it):
    the planner, the controller, the navigator, recovery and the way probe.

    Attributes:
        resolution_m: cell size, metres.
        origin: pose of cell (0, 0)'s lower-left corner in ``map``.
        footprint: the padded footprint polygon ``(N, 2)`` in ``base_link``, metres.
        inscribed_radius_m: the padded footprint's inscribed radius, metres.
        circumscribed_radius_m: the padded footprint's circumscribed radius, metres.
    """

    resolution_m: float
    origin: Pose2D
    footprint: FloatArray
    inscribed_radius_m: float
    circumscribed_radius_m: float

    @property
    def cost_scaling_factor(self) -> float:
        """The inflation's exponential decay rate, 1/m."""
        ...

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the grid."""
        ...

    def costs(self) -> U8Array:
        """An immutable snapshot of the cost grid (row 0 at the bottom)."""
        ...

    def world_to_cell(self, x_m: float, y_m: float) -> tuple[int, int]:
        """``(row, col)`` of the cell holding a ``map`` point (may lie outside the grid)."""
        ...

    def in_bounds(self, row: int, col: int) -> bool:
        """Whether a cell lies on the grid."""
        ...

    def cost_at(self, x_m: float, y_m: float) -> int:
        """Cost of the cell under a ``map`` point (``LETHAL`` off the grid)."""
        ...

    def footprint_costs(self, poses_in_map: FloatArray) -> U8Array:
        """Max cost under the footprint for each ``(N, 3)`` pose ``[x, y, yaw]`` in ``map``."""
        ...

    def clear_around(self, pose_in_map: Pose2D, radius_m: float) -> None:
        """Forget obstacle-layer marks within ``radius_m`` of a pose (recovery)."""
        ...
