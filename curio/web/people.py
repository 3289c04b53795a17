"""The dashboard's people frames: tracked people and, in simulation, the visitors' truth.

Both are JSON text frames offered on their own stream keys (the latest wins, per client, at
the client's rate), so the page can draw tracks with velocity arrows and, in simulation, the
visitors themselves:

* ``{"t": "people", "stamp", "tracks": [{"id", "x", "y", "vx", "vy", "std", "moving",
  "walked"}]}`` from ``/people`` (``map``: m, m/s);
* ``{"t": "people_truth", "stamp", "people": [{"id", "x", "y", "vx", "vy", "r",
  "behaviour", "state"}]}`` from ``/people/ground_truth`` (simulator only).

"Excuse me" reaches the page as an ordinary event (``people.excuse_me``).
"""

from __future__ import annotations

from curio.core.jsonable import to_json
from curio.core.messages import PeopleTracks, SimPeople

__all__ = ["people_frame", "truth_frame"]


def people_frame(msg: PeopleTracks) -> str:
    """The tracks as a ``people`` frame (positions and velocities rounded to mm, mm/s)."""
    return to_json({"t": "people", "stamp": msg.stamp, "tracks": [
        {"id": t.track_id, "x": round(t.x_m, 3), "y": round(t.y_m, 3),
         "vx": round(t.vx_mps, 3), "vy": round(t.vy_mps, 3), "std": round(t.pos_std_m, 3),
         "moving": t.moving, "walked": t.walked} for t in msg.tracks]})


def truth_frame(msg: SimPeople) -> str:
    """The simulated visitors as a ``people_truth`` frame."""
    return to_json({"t": "people_truth", "stamp": msg.stamp, "people": [
        {"id": p.person_id, "x": round(p.x_m, 3), "y": round(p.y_m, 3),
         "vx": round(p.vx_mps, 3), "vy": round(p.vy_mps, 3), "r": p.radius_m,
         "behaviour": p.behaviour, "state": p.state} for p in msg.people]})
