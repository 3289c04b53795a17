"""Recording, replay and the robotics ecosystem: Curio's runs as MCAP files.

* :mod:`curio.record.schemas` — JSON Schemas: Foxglove's well-known ones (``foxglove.LaserScan``,
  ``PoseInFrame``, ``PosesInFrame``, ``Grid``, ``FrameTransform``, ``SceneUpdate``, ``Log``) and
  one per Curio message for everything else.
* :mod:`curio.record.codec` — bus message ↔ recorded channel: the channel table (ROS-like names),
  the encoders and the decoders ``curio replay`` uses.
* :mod:`curio.record.queue` — the bounded queue (messages and bytes) between the loop and the
  writer thread.
* :mod:`curio.record.mcap_sink` — MCAP files: rotation by size and time, the disk budget, the
  flush policy.
* :mod:`curio.record.recorder` — the recorder part: a bus tap, the queue, the writer thread,
  health and counters.
* :mod:`curio.record.reader` — reading recordings back (also files cut short by a crash).
* :mod:`curio.record.library` — the recordings of a rover: list with a summary, safe download
  paths.
* :mod:`curio.record.foxglove_live` — the optional live Foxglove server (``curio[foxglove]``).
* :mod:`curio.record.compare` — where a replay diverges from its recording.
* :mod:`curio.record.wiring` — ``build_recorder`` for the composition root.
"""
