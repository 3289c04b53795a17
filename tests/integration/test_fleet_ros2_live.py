"""A running rover with ``fleet.ros2.enabled``: a plain Zenoh session (as rmw_zenoh's would)
sees the node and publisher tokens and receives /scan, /odom, /tf, /tf_static and /map, each
decodable by rosbags. (Not a real ROS 2 install: see docs/fleet.md.)"""

from __future__ import annotations

import threading

import pytest

from curio.app import App
from curio.core.clock import SimClock, wall_sleep
from curio.core.config import Config
from curio.fleet.zenoh_link import ZenohSettings, ZenohTransport, free_local_endpoint

TYPES = {"LaserScan_": "sensor_msgs/msg/LaserScan", "Odometry_": "nav_msgs/msg/Odometry",
         "TFMessage_": "tf2_msgs/msg/TFMessage", "OccupancyGrid_": "nav_msgs/msg/OccupancyGrid"}


async def test_a_ros2_listener_sees_the_rover(cfg: Config) -> None:
    pytest.importorskip("zenoh")
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    ep = free_local_endpoint()
    router = ZenohTransport("listener", ZenohSettings("router", listen=(ep,)))
    router.open()
    cfg = cfg.model_copy(update={"fleet": cfg.fleet.model_copy(update={
        "enabled": True, "rover": "r1",
        "ros2": cfg.fleet.ros2.model_copy(update={"enabled": True})})})
    got: dict[str, list[bytes]] = {}
    tokens: list[str] = []
    lock = threading.Lock()

    def on_data(sample) -> None:
        with lock:
            got.setdefault(str(sample.key_expr), []).append(sample.payload.to_bytes())

    router.session.declare_subscriber("0/**", on_data)
    router.session.liveliness().declare_subscriber(
        "@ros2_lv/**", lambda s: tokens.append(str(s.key_expr)) if str(s.kind).endswith("PUT")
        else None, history=True)
    clock = SimClock()
    app = App(cfg, clock, fleet_transport=ZenohTransport(
        "r1", ZenohSettings("client", connect=(ep,))))
    await app.start()
    await clock.run(until_s=3.0)
    want = {"map", "odom", "scan", "tf", "tf_static"}
    for _ in range(200):  # deliveries arrive on Zenoh's threads: wait for them (at most 10 s)
        with lock:
            if want <= {key.split("/")[2] for key in got}:
                break
        wall_sleep(0.05)
    await app.stop()
    router.close()
    topics = {key.split("/")[2]: key for key in got}
    assert sorted(topics) == ["map", "odom", "scan", "tf", "tf_static"]
    for key, payloads in got.items():
        msg = store.deserialize_cdr(payloads[-1], TYPES[key.split("::")[-1].split("/")[0]])
        assert msg is not None
    assert sum("/NN/" in t for t in tokens) == 1 and sum("/MP/" in t for t in tokens) == 5
    assert all(t.startswith("@ros2_lv/0/") and "/%r1/curio" in t for t in tokens)
