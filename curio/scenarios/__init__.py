"""Scripted scenarios for ``curio sim``: a registry of names to scenario classes.

Each scenario lives in its own module; the registry imports it only when it is run.
"""

from __future__ import annotations

import importlib

from curio.scenarios.base import Scenario

# name -> "module:Class"; each subsystem adds its scenarios here.
SCENARIOS: dict[str, str] = {
    "square": "curio.scenarios.square:SquareScenario",
    "goto": "curio.scenarios.goto:GotoScenario",
    "tour": "curio.scenarios.tour:TourScenario",
    "kidnap": "curio.scenarios.kidnap:KidnapScenario",
    "operator-demo": "curio.scenarios.operator_demo:OperatorDemoScenario",
    "blocked-door": "curio.scenarios.blocked_door:BlockedDoorScenario",
    "guided-tour": "curio.scenarios.guided_tour:GuidedTourScenario",
    "tour-day": "curio.scenarios.tour_day:TourDayScenario",
    "low-battery": "curio.scenarios.low_battery:LowBatteryScenario",
    "keepout": "curio.scenarios.keepout:KeepoutScenario",
    "lost": "curio.scenarios.lost:LostScenario",
    "crowd": "curio.scenarios.crowd:CrowdScenario",
}


def get_scenario(name: str) -> Scenario:
    """Instantiate the scenario called ``name``.

    Raises:
        KeyError: with the list of known scenarios.
    """
    try:
        target = SCENARIOS[name]
    except KeyError:
        known = ", ".join(sorted(SCENARIOS))
        raise KeyError(f"unknown scenario '{name}'; known scenarios: {known}") from None
    module_name, _, class_name = target.partition(":")
    cls = getattr(importlib.import_module(module_name), class_name)
    scenario: Scenario = cls()
    return scenario
