"""Fleet scenarios of ``curio fleet sim``: several rovers (each its own application) in one
simulated building, with or without the fleet manager.

The registry maps a name to ``"module:Class"``; the module is imported only when run.
"""

from __future__ import annotations

import importlib
from typing import cast

from curio.scenarios.fleet.base import FleetScenario

FLEET_SCENARIOS: dict[str, str] = {
    "tour-day": "curio.scenarios.fleet.tour_day:FleetTourDay",
    "doorway": "curio.scenarios.fleet.doorway:DoorwayScenario",
    "disconnect": "curio.scenarios.fleet.disconnect:DisconnectScenario",
}


def get_fleet_scenario(name: str) -> FleetScenario:
    """Instantiate the fleet scenario called ``name`` (KeyError listing the known ones)."""
    if name not in FLEET_SCENARIOS:
        raise KeyError(f"unknown fleet scenario '{name}'; known: "
                       f"{', '.join(sorted(FLEET_SCENARIOS))}")
    module_name, _, class_name = FLEET_SCENARIOS[name].partition(":")
    return cast(FleetScenario, getattr(importlib.import_module(module_name), class_name)())
