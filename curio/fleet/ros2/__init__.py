"""ROS 2 can listen: Curio's ``/scan``, ``/odom``, ``/tf`` and ``/map`` as ROS 2 messages over
Zenoh, the way ``rmw_zenoh`` carries them.

* :mod:`~curio.fleet.ros2.msgs` — the ROS 2 message definitions Curio publishes, their
  RIHS01 type hashes (REP-2016, computed from the definitions) and a CDR serializer driven by
  the same definitions;
* :mod:`~curio.fleet.ros2.rmw` — ``rmw_zenoh``'s key expressions, liveliness tokens, QoS
  strings and publication attachments;
* :mod:`~curio.fleet.ros2.publisher` — the rover's part that publishes them
  (``fleet.ros2.enabled``).

What was and was not tried against a real ROS 2 install is stated in ``docs/fleet.md``.
"""
