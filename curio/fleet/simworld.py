"""Several rovers in one simulated building: the others as bodies in each rover's world.

Each rover of a simulated fleet runs its own application with its own
:class:`~curio.sim.world.World` (its own physics, sensors and noise). :class:`PeerBodies`
puts every *other* rover into that world as a box of the footprint's size at its true pose, so
each rover's lidar sees the others, its collision check refuses to drive into them (a
``collision`` event with the box), and rover-rover contacts are counted like any other.

The true poses come either straight from the other worlds (one process, ``curio fleet sim``:
:meth:`PeerBodies.place` every physics step, before the step) or over the fleet link
(``fleet.share_sim_truth``: each rover publishes ``curio/<rover>/sim/truth`` and
:meth:`PeerBodies.on_truth` places what it hears — rovers in separate processes on real time).
"""

from __future__ import annotations

from typing import Any

from curio.core.geometry import Pose2D
from curio.robot import RobotModel
from curio.sim.world import World

__all__ = ["PeerBodies"]


class PeerBodies:
    """The other rovers as boxes in ``world`` (see the module docstring).

    Args:
        world: this rover's simulated world.
        robot: the robot model (all rovers share its footprint; its bounding box is used).
    """

    def __init__(self, world: World, robot: RobotModel) -> None:
        self.world = world
        fp = robot.footprint
        self.length_m = float(fp[:, 0].max() - fp[:, 0].min())
        self.width_m = float(fp[:, 1].max() - fp[:, 1].min())
        self.offset_m = float(fp[:, 0].max() + fp[:, 0].min()) / 2.0
        self._ids: dict[str, int] = {}
        self._names: dict[int, str] = {}

    def place(self, name: str, pose: Pose2D) -> None:
        """Put rover ``name``'s body at its true pose (``base_link`` in ``map``)."""
        centre = pose @ Pose2D(self.offset_m, 0.0, 0.0)
        oid = self._ids.get(name)
        if oid is None:
            oid = self.world.add_box(centre.x, centre.y, self.length_m, self.width_m, centre.yaw)
            self._ids[name] = oid
            self._names[oid] = name
        else:
            self.world.move_box(oid, centre.x, centre.y, centre.yaw)

    def remove(self, name: str) -> None:
        """Take rover ``name`` out of this world."""
        oid = self._ids.pop(name, None)
        if oid is not None:
            self._names.pop(oid, None)
            self.world.remove_object(oid)

    def on_truth(self, name: str, msg: dict[str, Any]) -> None:
        """A ``sim/truth`` message from rover ``name`` (malformed ones are ignored)."""
        try:
            self.place(name, Pose2D(float(msg["x"]), float(msg["y"]), float(msg["yaw"])))
        except (KeyError, TypeError, ValueError):
            return

    def rover_of(self, hit: str) -> str | None:
        """The rover a collision's ``with`` entry (``box:ID``) names, or None."""
        kind, _, number = hit.partition(":")
        if kind != "box" or not number.isdigit():
            return None
        return self._names.get(int(number))

    @property
    def names(self) -> list[str]:
        """The rovers placed so far."""
        return sorted(self._ids)
