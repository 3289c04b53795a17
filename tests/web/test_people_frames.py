"""The hub forwards tracked people and the simulated visitors' truth as JSON frames."""

from __future__ import annotations

import json
from typing import Any

from aiohttp import WSMsgType

from curio.core.messages import PeopleTracks, PersonTrack, SimPeople, SimPerson
from curio.core.topics import PEOPLE, PEOPLE_TRUTH
from tests.web.conftest import MakeDash
from tests.web.test_hub import connect, spin


async def test_people_and_truth_frames(make_dash: MakeDash) -> None:
    d = await make_dash()
    d.bus.publish(PEOPLE, PeopleTracks(2.0, (PersonTrack(7, 1.2345, -0.5, 0.8, 0.1,
                                                         walked=True, moving=True),)))
    d.bus.publish(PEOPLE_TRUTH, SimPeople(2.0, (SimPerson(3, 4.0, 5.0, 0.0, -1.0, 0.2,
                                                          "crosser"),)))
    await spin()
    ws = await connect(d)  # the latest frames arrive with the snapshot
    frames: dict[str, dict[str, Any]] = {}
    while len(frames) < 2:
        msg = await ws.receive(timeout=5.0)
        if msg.type == WSMsgType.TEXT:
            data = json.loads(msg.data)
            if data["t"] in ("people", "people_truth"):
                frames[data["t"]] = data
    assert frames["people"]["tracks"] == [{"id": 7, "x": 1.234, "y": -0.5, "vx": 0.8,
                                           "vy": 0.1, "std": 0.0, "moving": True,
                                           "walked": True}]
    person = frames["people_truth"]["people"][0]
    assert (person["id"], person["behaviour"], person["vy"]) == (3, "crosser", -1.0)
    await ws.close()
