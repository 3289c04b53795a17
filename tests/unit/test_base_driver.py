"""The base-driver interface: the Arduino's base and the simulated base both implement it."""

from __future__ import annotations

import inspect

from curio.drivers.arduino.driver import ArduinoBase
from curio.drivers.base import BaseDriver
from curio.sim.base import SimBase


def test_both_bases_implement_the_interface() -> None:
    for cls in (ArduinoBase, SimBase):
        assert BaseDriver in cls.__mro__  # declared, so mypy checks the signatures
        for verb in ("run", "halt", "close"):
            method = getattr(cls, verb)
            assert method is not getattr(BaseDriver, verb), (cls, verb)  # its own, not the stub
            assert inspect.iscoroutinefunction(method)
